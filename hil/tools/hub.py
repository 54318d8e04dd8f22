"""A loopback CAN hub speaking the socketcand protocol, so separate processes share one bus without vcan.

Where SocketCAN/vcan does not exist, the emulator (``qomni.hil.device.server``) and a master
(``qomni.hil.master.client``, CANoe via socketcand, candump-like tools) in different processes meet on this
hub: every client connects with python-can's own ``socketcand`` interface, unchanged::

    hub = Hub().start()                                   # 127.0.0.1, free port
    bus = can.Bus(interface="socketcand", host="127.0.0.1", port=hub.port, channel="can0")

A frame one client sends reaches every other client in raw mode on the same channel name, never the
sender (like a CAN controller without self-reception; python-can buses do not receive their own frames
either). Different channel names are separate buses. Stand-alone: ``python -m qomni.hil.tools.hub --port 29536``.

Protocol (socketcand, https://github.com/linux-can/socketcand ``doc/protocol.md``; the subset python-can's
``can.interfaces.socketcand`` client uses), ASCII, each element ``< ... >``:

* hub → client on connect: ``< hi >``;
* ``< open CHANNEL >`` → ``< ok >`` (BCM mode; the hub offers no broadcast-manager jobs);
* ``< rawmode >`` → ``< ok >``; from then on each frame of another client arrives as
  ``< frame ID SEC.USEC DATA >`` (ID 3 hex digits standard, 8 extended; SEC.USEC the hub's receive time
  [s, Unix epoch]; DATA hex without spaces, empty for DLC 0);
* ``< send ID LEN B0 B1 ... >`` (ID hex, 3 digits standard / 8 extended, LEN 0…8, bytes hex) in BCM or raw
  mode sends a frame; ``< bcmode >`` leaves raw mode; ``< echo >`` → ``< echo >``;
* anything else → ``< error TEXT >`` (the connection stays open; an over-long element closes it).

Hot path: each connection is an :class:`asyncio.Protocol` whose ``data_received`` parses the read at once
(no stream reader, no task woken per read: one event-loop iteration per read); the frames of one read
from a client are forwarded to each other client in one write (a device's TPDOs of a SYNC, sent in one
write, leave the hub in one write); a well-formed
``< send ID LEN B… >`` with a standard ID is recognised by one regular expression, every other element
goes through the full parser with its error answers.

Bounds: at most ``max_clients`` connections (more are told ``< error too many clients >`` and closed),
at most ``max_buffer`` bytes queued towards one client (further frames to that client are dropped and
counted in :attr:`Hub.dropped`, like a receive-queue overrun; a client that does not read the answers to
its own commands is disconnected), elements of at most 256 characters.

Binding is to 127.0.0.1 only: this project never puts CAN traffic on a network (docs: DESIGN.md,
"CAN side facts").

Standard library only (asyncio) besides python-can for :func:`open_hub_bus`.
"""
from __future__ import annotations

import argparse
import asyncio
import logging
import socket
import threading
import time
from dataclasses import dataclass

from ..busy_poll import PollingSelector, check_busy
from .socketcand_text import FAST_SEND, REMOTE, parse_send as _parse_send, stamp as frame_stamp

logger = logging.getLogger(__name__)

LOOPBACK = "127.0.0.1"
DEFAULT_CHANNEL = "can0"
_MAX_ELEMENT = 256                   # characters of one "< ... >" element
_COMMANDS_BEFORE_OPEN = {"open", "echo"}


def _check_host(host: str) -> str:
    if host != LOOPBACK:
        raise ValueError(f"the hub binds to {LOOPBACK} only (loopback; this project never puts CAN "
                         f"traffic on a network), got host {host!r}")
    return host


def hub_bus_spec(port: int, channel: str = DEFAULT_CHANNEL, host: str = LOOPBACK) -> str:
    """Bus spec of a hub connection in the grammar ``socketcand:HOST:PORT/CHANNEL``.

    :func:`qomni.hil.bus.open_bus` opens it, so ``--bus`` options and :class:`qomni.hil.device.server.VehicleServer` /
    :class:`qomni.hil.master.client.VehicleClient` take it as a string.

    Args:
        port: TCP port of the hub (:attr:`Hub.port`), 1…65535.
        channel: socketcand channel name (one hub carries independent buses per name).
        host: must be 127.0.0.1.
    Raises:
        ValueError: non-loopback host, port out of range, or a channel with whitespace, ``<``, ``>``,
            ``@`` or ``/``.
    """
    _check_host(host)
    _check_port(port, allow_zero=False)
    _check_channel(channel)
    return f"socketcand:{host}:{port}/{channel}"


def open_hub_bus(port: int, channel: str = DEFAULT_CHANNEL, **kwargs):
    """A python-can ``socketcand`` bus connected to the hub on 127.0.0.1:``port``.

    Args:
        port: TCP port of the hub (:attr:`Hub.port`).
        channel: socketcand channel name.
        kwargs: passed to ``can.Bus`` (e.g. ``tcp_tune=True`` sets TCP_NODELAY: lower latency).
    Returns:
        ``can.interfaces.socketcand.SocketCanDaemonBus``; close it with ``shutdown()``.
    Raises:
        ValueError: port out of range or a bad channel name.
        TimeoutError: nothing listens on the port (python-can retries for 10 s).
        can.CanError: the handshake failed.
    """
    import can

    _check_port(port, allow_zero=False)
    _check_channel(channel)
    return can.Bus(interface="socketcand", host=LOOPBACK, port=port, channel=channel, **kwargs)


def _check_port(port: int, allow_zero: bool) -> int:
    if not isinstance(port, int) or isinstance(port, bool) or not (0 if allow_zero else 1) <= port <= 65535:
        raise ValueError(f"port must be an integer in {'0' if allow_zero else '1'}…65535, got {port!r}")
    return port


def _check_channel(channel: str) -> str:
    if not isinstance(channel, str) or not channel or any(c.isspace() or c in "<>@/" for c in channel):
        raise ValueError(f"channel must be a non-empty name without whitespace, '<', '>', '@', '/', "
                         f"got {channel!r}")
    return channel


@dataclass(eq=False)
class _Client:
    transport: asyncio.Transport
    peer: str
    channel: str | None = None
    raw: bool = False
    pending: list[bytes] | None = None        # frames held back during the raw-mode grace period
    pending_bytes: int = 0
    release: asyncio.TimerHandle | None = None

    def reply(self, text: bytes, limit: int) -> None:
        """Answer a command; a client that lets ``limit`` bytes of answers pile up is disconnected."""
        if self.transport.get_write_buffer_size() > limit:
            logger.warning("hub: %s does not read its answers, closing", self.peer)
            self.transport.abort()
        else:
            self.transport.write(text)


class _Connection(asyncio.Protocol):
    """One client's connection: the hub's protocol on asyncio's transport callbacks. Each read is
    parsed in ``data_received`` itself, without a stream reader and a task to wake for it."""

    def __init__(self, hub: "Hub"):
        self.hub = hub
        self.client: _Client | None = None
        self.buffer = b""
        self.sock = None
        self.quickack = 0
        self.unopened: asyncio.TimerHandle | None = None

    def connection_made(self, transport: asyncio.Transport) -> None:
        hub = self.hub
        sock = transport.get_extra_info("socket")
        if sock is not None:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self.sock, self.quickack = sock, getattr(socket, "TCP_QUICKACK", 0)
        peer = "%s:%s" % transport.get_extra_info("peername")[:2]
        if len(hub._clients) >= hub.max_clients:
            logger.warning("hub: refusing %s, already %d clients", peer, len(hub._clients))
            transport.write(b"< error too many clients >")
            transport.close()
            return
        self.client = _Client(transport, peer)
        hub._clients.add(self.client)
        logger.debug("hub: %s connected", peer)
        self.unopened = hub._loop.call_later(hub.open_timeout, hub._close_unopened, self.client)
        transport.write(b"< hi >")

    def data_received(self, chunk: bytes) -> None:
        client = self.client
        if client is None or client not in self.hub._clients:
            return
        if self.quickack:
            # Acknowledge at once: python-can's client does not disable Nagle's algorithm, so its next
            # small frame would wait for our (delayed, ~40 ms) acknowledgement.
            try:
                self.sock.setsockopt(socket.IPPROTO_TCP, self.quickack, 1)
            except OSError:
                pass
        hub = self.hub
        buffer = self.buffer + chunk if self.buffer else chunk
        lines: list[bytes] = []                   # frames of this read, forwarded in one write per client
        stamp = frame_stamp(time.time()).encode("ascii")
        start = 0
        while True:
            end = buffer.find(b">", start)
            if end < 0:
                break
            element, start = buffer[start:end + 1], end + 1
            line = hub._fast_frame(client, element, stamp)
            if line is not None:
                lines.append(line)
                continue
            if lines:
                hub._forward(client, lines)
                lines = []
            hub._handle(client, element)
        self.buffer = buffer[start:]
        if lines:
            hub._forward(client, lines)
        if len(self.buffer) > _MAX_ELEMENT:
            client.transport.write(b"< error element too long >")
            logger.warning("hub: %s sent an element over %d characters, closing", client.peer, _MAX_ELEMENT)
            self._drop()
            client.transport.close()

    def eof_received(self) -> bool:
        return False                              # close the connection

    def connection_lost(self, exc) -> None:
        self._drop()

    def _drop(self) -> None:
        if self.unopened is not None:
            self.unopened.cancel()
        if self.client is not None and self.client in self.hub._clients:
            self.hub._clients.discard(self.client)
            logger.debug("hub: %s disconnected", self.client.peer)


class Hub:
    """socketcand-protocol CAN hub on 127.0.0.1 (module docstring for the protocol).

    Args:
        port: TCP port, 0 = let the OS choose (read :attr:`port` after :meth:`start`).
        host: must be 127.0.0.1.
        max_clients: maximum simultaneous connections.
        max_buffer: bytes, maximum output queued towards one client; beyond, frames to it are dropped.
        handshake_grace: s, delay between the ``< ok >`` answering ``< rawmode >`` and the first frame
            forwarded to that client (frames meanwhile are queued, not lost). python-can's client reads
            the ``< ok >`` with one ``recv`` and compares it exactly, so a frame arriving in the same
            ``recv`` would break its handshake.
        open_timeout: s a connection may take to open a channel; one that has not is closed, so idle
            connections cannot hold the hub's places.
        busy_poll: s the event loop polls its sockets before it blocks (:mod:`qomni.hil.busy_poll`;
            0: block at once).
    Attributes:
        frames: frames accepted from clients so far.
        dropped: frames not delivered to some client because its queue was full.
        remote_dropped: remote (RTR) requests not forwarded: socketcand's ``< frame >`` has no RTR flag, and
            the CANopen devices here answer none (CiA 301 advises against RTR).
    Raises:
        ValueError: non-loopback host, port out of range, ``max_clients`` < 1, ``max_buffer`` < 256, or
            ``busy_poll`` negative or not finite.
    """

    def __init__(self, port: int = 0, host: str = LOOPBACK, *, max_clients: int = 16,
                 max_buffer: int = 1 << 20, handshake_grace: float = 0.05, open_timeout: float = 5.0,
                 busy_poll: float = 0.0):
        self._host = _check_host(host)
        self.busy_poll = check_busy(busy_poll)
        self._requested_port = _check_port(port, allow_zero=True)
        if max_clients < 1 or max_buffer < _MAX_ELEMENT:
            raise ValueError(f"max_clients must be >= 1 and max_buffer >= {_MAX_ELEMENT} bytes")
        self.max_clients = int(max_clients)
        self.max_buffer = int(max_buffer)
        self.handshake_grace = float(handshake_grace)
        self.open_timeout = float(open_timeout)
        self.frames = 0
        self.dropped = 0
        self.remote_dropped = 0
        self._port: int | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: asyncio.base_events.Server | None = None
        self._thread: threading.Thread | None = None
        self._clients: set[_Client] = set()

    # ------------------------------------------------------------ lifecycle
    @property
    def port(self) -> int:
        """The TCP port the hub listens on. Raises RuntimeError when not started (or stopped)."""
        if self._port is None:
            raise RuntimeError("hub not started")
        return self._port

    @property
    def host(self) -> str:
        """Always 127.0.0.1."""
        return self._host

    @property
    def clients(self) -> int:
        """Number of connected clients."""
        return len(self._clients)

    def bus_spec(self, channel: str = DEFAULT_CHANNEL) -> str:
        """:func:`hub_bus_spec` of this hub (see the note there)."""
        return hub_bus_spec(self.port, channel)

    def open_bus(self, channel: str = DEFAULT_CHANNEL, **kwargs):
        """:func:`open_hub_bus` on this hub."""
        return open_hub_bus(self.port, channel, **kwargs)

    def start(self) -> "Hub":
        """Bind 127.0.0.1:port and serve in a background thread; returns self.

        Raises:
            RuntimeError: already started.
            OSError: the port cannot be bound (e.g. in use).
        """
        if self._thread is not None:
            raise RuntimeError("hub already started")
        loop = asyncio.SelectorEventLoop(PollingSelector(self.busy_poll)) if self.busy_poll > 0 \
            else asyncio.new_event_loop()
        self._loop = loop                  # before the first connection can be accepted (its timers)
        try:
            self._server = loop.run_until_complete(loop.create_server(
                lambda: _Connection(self), self._host, self._requested_port, family=socket.AF_INET))
        except BaseException:
            self._loop = None
            loop.close()
            raise
        self._port = self._server.sockets[0].getsockname()[1]
        self._thread = threading.Thread(target=loop.run_forever, name=f"hil-hub-{self._port}", daemon=True)
        self._thread.start()
        logger.info("CAN hub (socketcand protocol) on %s:%d", self._host, self._port)
        return self

    def stop(self, timeout: float = 2.0) -> None:
        """Close every connection and the listening socket, stop the thread; idempotent."""
        loop, thread = self._loop, self._thread
        if loop is None or thread is None:
            return
        try:
            asyncio.run_coroutine_threadsafe(self._shutdown(), loop).result(timeout)
        except Exception:                                  # noqa: BLE001
            logger.exception("hub shutdown incomplete")
        finally:
            loop.call_soon_threadsafe(loop.stop)
            thread.join(timeout)
            if not thread.is_alive():
                loop.close()
            self._loop = self._thread = self._server = None
            self._port = None

    def __enter__(self) -> "Hub":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    async def _shutdown(self) -> None:
        self._server.close()
        for client in list(self._clients):
            client.transport.abort()                  # do not wait for a stalled client to read
        self._clients.clear()
        await asyncio.sleep(0)                        # let the aborted connections' callbacks run

    # ------------------------------------------------------------ protocol
    def _close_unopened(self, client: _Client) -> None:
        if client.channel is None and client in self._clients:
            logger.warning("hub: %s opened no channel within %g s, closing", client.peer, self.open_timeout)
            client.transport.abort()

    def _handle(self, client: _Client, element: bytes) -> None:
        def reply(text: bytes) -> None:
            client.reply(text, self.max_buffer)

        try:
            text = element.decode("ascii")
        except UnicodeDecodeError:
            reply(b"< error not ascii >")
            return
        start = text.find("<")
        if start < 0:
            reply(b"< error missing '<' >")
            return
        words = text[start + 1:-1].split()
        if not words:
            reply(b"< error empty command >")
            return
        command, args = words[0], words[1:]
        if client.channel is None and command not in _COMMANDS_BEFORE_OPEN:
            reply(b"< error open a channel first >")
            return
        if command == "echo":
            reply(b"< echo >")
        elif command == "open":
            if client.channel is not None:
                reply(b"< error channel already open >")
            elif len(args) != 1 or any(c in "@/" for c in args[0]):
                reply(b"< error usage: open CHANNEL >")
            else:
                client.channel = args[0]
                reply(b"< ok >")
        elif command == "rawmode":
            reply(b"< ok >")
            if not client.raw:
                client.raw = True
                client.pending, client.pending_bytes = [], 0
                client.release = self._loop.call_later(self.handshake_grace, self._release, client)
        elif command == "bcmode":
            client.raw = False
            client.pending = None
            if client.release is not None:
                client.release.cancel()
            reply(b"< ok >")
        elif command == "send":
            frame = _parse_send(args)
            if frame is REMOTE:
                self.remote_dropped += 1             # no answer: python-can reads "< error >" as a frame
                if self.remote_dropped == 1:
                    logger.warning("hub: %s sent a remote (RTR) request; RTR is not forwarded", client.peer)
            elif isinstance(frame, str):
                reply(f"< error {frame} >".encode("ascii"))
            else:
                self._broadcast(client, *frame)
        else:
            reply(f"< error unknown command {command[:32]} >".encode("ascii", "replace"))

    def _release(self, client: _Client) -> None:
        pending, client.pending = client.pending, None
        if pending and client.raw and client in self._clients:
            client.transport.write(b"".join(pending))

    def _fast_frame(self, sender: _Client, element: bytes, stamp: bytes) -> bytes | None:
        """The ``< frame … >`` line of a well-formed standard-ID data frame ``< send ID LEN B… >`` from a
        client with an open channel (the hot path: no decoding into words, no error texts); None for
        every other element, which :meth:`_handle` then answers."""
        match = FAST_SEND.fullmatch(element)
        if match is None or sender.channel is None:
            return None
        can_id, length = int(match[1], 16), int(match[2])
        data = bytes(int(b, 16) for b in match[3].split())
        if can_id > 0x7FF or len(data) != length:
            return None
        self.frames += 1
        return b"< frame %03X %b %b >" % (can_id, stamp, data.hex().upper().encode("ascii"))

    def _broadcast(self, sender: _Client, can_id: int, extended: bool, data: bytes) -> None:
        self.frames += 1
        ident = f"{can_id:08X}" if extended else f"{can_id:03X}"
        self._forward(sender, [f"< frame {ident} {frame_stamp(time.time())} {data.hex().upper()} >".encode("ascii")])

    def _forward(self, sender: _Client, lines: list[bytes]) -> None:
        """Hand frame lines (in order) to every other raw-mode client on the sender's channel, in one write
        per client; a client whose queue cannot take them all gets those that fit, the rest is dropped."""
        joined, total = (lines[0], len(lines[0])) if len(lines) == 1 else (None, sum(map(len, lines)))
        for client in self._clients:
            if client is sender or not client.raw or client.channel != sender.channel:
                continue
            if client.pending is not None:
                for line in lines:
                    if client.pending_bytes + len(line) > self.max_buffer:
                        self.dropped += 1
                    else:
                        client.pending.append(line)
                        client.pending_bytes += len(line)
                continue
            room = self.max_buffer - client.transport.get_write_buffer_size()
            if total <= room:
                if joined is None:
                    joined = b"".join(lines)
                client.transport.write(joined)
                continue
            for line in lines:
                if len(line) > room:
                    self.dropped += 1
                else:
                    client.transport.write(line)
                    room -= len(line)


def main(argv: list[str] | None = None) -> None:
    """``python -m qomni.hil.tools.hub [--port N]``: run a hub on 127.0.0.1 until interrupted (Ctrl-C)."""
    parser = argparse.ArgumentParser(prog="python -m qomni.hil.tools.hub",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--port", type=int, default=29536, help="TCP port on 127.0.0.1 (0: any free port)")
    parser.add_argument("--max-clients", type=int, default=16)
    parser.add_argument("--busy-poll", type=float, default=0.0, metavar="S",
                        help="poll the sockets for up to S seconds before blocking (qomni.hil.busy_poll)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    hub = Hub(args.port, max_clients=args.max_clients, busy_poll=args.busy_poll).start()
    print(f"hub listening on {LOOPBACK}:{hub.port}; python-can: can.Bus(interface='socketcand', "
          f"host='{LOOPBACK}', port={hub.port}, channel='{DEFAULT_CHANNEL}')", flush=True)
    try:
        threading.Event().wait()
    except KeyboardInterrupt:
        pass
    finally:
        hub.stop()


if __name__ == "__main__":
    main()
