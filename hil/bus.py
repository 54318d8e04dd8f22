"""Bus specification strings → python-can buses.

Grammar: ``INTERFACE[:CHANNEL][@BITRATE]``, e.g. ``"virtual"``, ``"virtual:rig1"``, ``"socketcan:can0"``,
``"pcan:PCAN_USBBUS1@1M"``, ``"kvaser:0@500k"``. ``INTERFACE`` is a python-can interface name;
``BITRATE`` is bit/s with an optional ``k``/``M`` suffix. Only ``virtual`` may omit the channel (it
defaults to :data:`DEFAULT_VIRTUAL_CHANNEL`; all ``virtual`` buses of one process on one channel see
each other's frames). ``udp_multicast`` is refused: this project never puts CAN traffic on a network.

``socketcand`` (a hub, see :mod:`qomni.hil.tools.hub`) takes ``socketcand:HOST:PORT/CHANNEL`` with HOST 127.0.0.1
only, e.g. ``socketcand:127.0.0.1:29536/can0``.
"""
from __future__ import annotations

import contextlib
import logging
import re
import threading
from dataclasses import dataclass

import can
from can.interfaces.socketcand.socketcand import (SocketCanDaemonBus,
                                                 convert_can_message_to_ascii_message)

from .busy_poll import check_busy, poll_first
from .virtual_bus import InlineVirtualBus

DEFAULT_VIRTUAL_CHANNEL = "qomni"
_FORBIDDEN = {"udp_multicast": "it sends frames to a non-loopback multicast address"}
_BITRATE = re.compile(r"^(\d+(?:\.\d+)?)([kKmM]?)$")


@dataclass(frozen=True)
class BusSpec:
    """A parsed bus specification: python-can ``interface``, ``channel`` and optional ``bitrate`` [bit/s]."""

    interface: str
    channel: str
    bitrate: int | None = None
    host: str | None = None
    port: int | None = None

    def __str__(self) -> str:
        where = self.channel if self.host is None else f"{self.host}:{self.port}/{self.channel}"
        text = f"{self.interface}:{where}"
        return text if self.bitrate is None else f"{text}@{self.bitrate}"


def parse_bus_spec(spec: str) -> BusSpec:
    """Parse ``INTERFACE[:CHANNEL][@BITRATE]``.

    Raises:
        ValueError: empty spec, unknown or forbidden interface, missing channel (all but ``virtual``),
            or a bitrate that is not a positive number of bit/s (``500000``, ``500k``, ``1M``).
    """
    if not isinstance(spec, str) or not spec.strip():
        raise ValueError(f"bus spec must be a non-empty string like 'virtual' or 'socketcan:can0', got {spec!r}")
    text = spec.strip()
    bitrate = None
    if "@" in text:
        text, _, rate = text.rpartition("@")
        bitrate = _parse_bitrate(rate, spec)
    interface, sep, channel = text.partition(":")
    interface, channel = interface.strip(), channel.strip()
    if interface in _FORBIDDEN:
        raise ValueError(f"bus spec {spec!r}: interface '{interface}' is not allowed: {_FORBIDDEN[interface]}")
    if interface not in can.interfaces.VALID_INTERFACES:
        raise ValueError(
            f"bus spec {spec!r}: unknown interface '{interface}'; expected one of "
            f"{', '.join(sorted(set(can.interfaces.VALID_INTERFACES) - set(_FORBIDDEN)))}")
    if not channel:
        if interface != "virtual" or sep:
            raise ValueError(f"bus spec {spec!r}: missing channel, write e.g. '{interface}:CHANNEL'")
        channel = DEFAULT_VIRTUAL_CHANNEL
    if interface == "socketcand":
        return _socketcand_spec(channel, bitrate, spec)
    return BusSpec(interface, channel, bitrate)


_SOCKETCAND = re.compile(r"^(?P<host>[^:/]+):(?P<port>\d+)/(?P<channel>\S+)$")
LOOPBACK = "127.0.0.1"


def _socketcand_spec(where: str, bitrate: int | None, spec: str) -> BusSpec:
    match = _SOCKETCAND.match(where)
    if not match:
        raise ValueError(f"bus spec {spec!r}: socketcand needs 'socketcand:127.0.0.1:PORT/CHANNEL'")
    host, port = match.group("host"), int(match.group("port"))
    if host != LOOPBACK:
        raise ValueError(f"bus spec {spec!r}: socketcand host must be {LOOPBACK}: this project never "
                         "puts CAN traffic on a network")
    if not 1 <= port <= 65535:
        raise ValueError(f"bus spec {spec!r}: port {port} is not in 1..65535")
    return BusSpec("socketcand", match.group("channel"), bitrate, host, port)


def open_bus(spec: str | BusSpec, *, busy_poll: float = 0.0, **kwargs) -> can.BusABC:
    """Open the python-can bus described by ``spec``; ``kwargs`` go to ``can.Bus`` unchanged.

    ``virtual`` opens a :class:`qomni.hil.virtual_bus.InlineVirtualBus` (a python-can ``virtual`` bus,
    peer of every other ``virtual`` bus of the process on the channel, that can deliver inline).
    ``busy_poll`` [s] (socketcand only): each receive polls that long before it blocks
    (:mod:`qomni.hil.busy_poll`).

    Raises:
        ValueError: bad spec (see :func:`parse_bus_spec`), or ``busy_poll`` on another interface.
        can.CanError: the interface could not be opened (driver missing, no such device).
    """
    parsed = spec if isinstance(spec, BusSpec) else parse_bus_spec(spec)
    if check_busy(busy_poll) > 0.0 and parsed.host is None:
        raise ValueError(f"bus spec {spec!r}: busy polling applies to socketcand (a qomni hub), not to "
                         f"'{parsed.interface}'")
    if parsed.bitrate is not None:
        kwargs.setdefault("bitrate", parsed.bitrate)
    if parsed.host is not None:
        logging.getLogger("can.interfaces.socketcand.socketcand").addFilter(_quiet_partial_reads)
        kwargs.setdefault("host", parsed.host)
        kwargs.setdefault("port", parsed.port)
        kwargs.setdefault("tcp_tune", True)
        return BatchingSocketcandBus(channel=parsed.channel, busy_poll=busy_poll, **kwargs)
    if parsed.interface == "virtual":
        return InlineVirtualBus(channel=parsed.channel, **kwargs)
    return can.Bus(interface=parsed.interface, channel=parsed.channel, **kwargs)


#: A byte as python-can's socketcand client writes it (lower-case hex, no leading zero).
_HEX = [f"{x:x}" for x in range(256)]


class BatchingSocketcandBus(SocketCanDaemonBus):
    """python-can's ``socketcand`` client that can hand several frames to TCP in one write: inside
    :meth:`batch`, the frames one thread sends are collected and written together when the block ends (a
    device's TPDOs of one SYNC: one segment, one wake-up of the hub and of the master, not ten).
    Frames other threads send meanwhile go out at once, as always. ``busy_poll`` [s]: a receive polls the
    socket that long before it blocks (:mod:`qomni.hil.busy_poll`; default 0, block at once)."""

    def __init__(self, *args, busy_poll: float = 0.0, **kwargs):
        self._batches = threading.local()
        self._busy_poll = check_busy(busy_poll)
        super().__init__(*args, **kwargs)

    def _recv_internal(self, timeout):
        """python-can's receive, polling the socket for up to ``busy_poll`` s before it blocks
        (:mod:`qomni.hil.busy_poll`)."""
        if self._busy_poll <= 0.0:
            return super()._recv_internal(timeout)
        return poll_first(super()._recv_internal, timeout, self._busy_poll, lambda got: got[0] is not None)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        pending = getattr(self._batches, "pending", None)
        if pending is None:
            super().send(msg, timeout)
        else:
            pending.append(convert_can_message_to_ascii_message(msg))

    def send_frame(self, can_id: int, data: bytes) -> None:
        """Send the 11-bit data frame ``can_id`` (≤ 0x7FF) with ``data`` (≤ 8 bytes) without a
        :class:`can.Message`: the text python-can's client writes for it, formatted directly. For senders
        whose frames are valid by construction; nothing is checked."""
        text = f"< send {can_id:03X} {len(data):X} {' '.join(map(_HEX.__getitem__, data))} >"
        pending = getattr(self._batches, "pending", None)
        if pending is None:
            self._tcp_send(text)
        else:
            pending.append(text)

    @contextlib.contextmanager
    def batch(self):
        """Collect this thread's frames until the block ends, then write them at once (also on error)."""
        if getattr(self._batches, "pending", None) is not None:      # nested: the outer block writes
            yield
            return
        self._batches.pending = []
        try:
            yield
        finally:
            pending, self._batches.pending = self._batches.pending, None
            if pending:
                self._tcp_send("".join(pending))


def batched(bus: can.BusABC):
    """``bus.batch()`` where the bus can write several frames at once (:class:`BatchingSocketcandBus`),
    else a block that changes nothing."""
    batch = getattr(bus, "batch", None)
    return batch() if batch is not None else contextlib.nullcontext()


def _quiet_partial_reads(record: logging.LogRecord) -> bool:
    """python-can's socketcand client warns on every TCP read that ends mid-frame; that is normal."""
    return "incomplete message" not in record.getMessage()


def _parse_bitrate(text: str, spec: str) -> int:
    match = _BITRATE.match(text.strip())
    if not match:
        raise ValueError(f"bus spec {spec!r}: bitrate '{text}' is not a number of bit/s like 500000, 500k, 1M")
    value = float(match.group(1)) * {"": 1, "k": 1e3, "m": 1e6}[match.group(2).lower()]
    if value <= 0 or value != int(value):
        raise ValueError(f"bus spec {spec!r}: bitrate '{text}' must be a positive whole number of bit/s")
    return int(value)
