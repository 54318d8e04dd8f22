"""Whole-bus recording: every frame the master receives and every frame it sends, to log files; and
replay of a log onto a bus.

A :class:`can.Listener` for the master's :class:`can.Notifier` (received frames) that the master also
calls for each frame it transmits (python-can buses do not hand own frames to notifiers). One recorder
writes one or several files at once; the suffix picks the format: :class:`can.BLFWriter` for ``.blf``
(Vector tools replay it), candump ``-L`` format for ``.log`` (:class:`can.CanutilsLogWriter`; can-utils'
``canplayer`` and ``log2asc`` read it), and python-can's other formats (``.asc``, ``.csv``, ``.trc``, …)
through :class:`can.Logger`.

The writers run in a process of their own (``python -m qomni.hil.tools.recorder FD``, a fresh
interpreter fed over a socket pair): python-can's writers format and pack every frame in Python, about
7 µs per frame for a BLF and a candump file together, which is 15 frames and a fifth of a lock-step
campaign's cycle. The master's thread only appends each frame's fields to a batch (timestamp,
identifier, DLC, data, flags) and hands the batch over, pickled, every :data:`BATCH_FRAMES` frames or
:data:`BATCH_AGE` seconds, whichever comes first; :meth:`BusRecorder.stop` hands over the rest and waits
until every file is flushed and closed. The files are what the same writers make in the master's
process: the frames' fields cross the socket unchanged.

:func:`replay` sends a recorded log onto a bus with its original timing (:class:`can.LogReader`,
:class:`can.MessageSync`).
"""
from __future__ import annotations

import logging
import os
import pickle
import socket
import subprocess
import sys
import threading
import time
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Callable, Sequence

import can

logger = logging.getLogger(__name__)


#: A frame in a batch: (timestamp [s], arbitration ID, DLC, data bytes, the can.Message flags below).
_FLAGS = ("is_extended_id", "is_remote_frame", "is_error_frame", "is_rx", "is_fd", "bitrate_switch",
          "error_state_indicator")
#: The flags of an 11-bit data frame, received and transmitted, in _FLAGS order.
_RX_DATA_FRAME = (False, False, False, True, False, False, False)
_TX_DATA_FRAME = (False, False, False, False, False, False, False)
#: Frames per batch handed to the writer process, and the age [s] after which a batch goes anyway.
BATCH_FRAMES = 512
BATCH_AGE = 0.1
#: s the writer process gets to open its files, and to write and close them on stop.
WRITER_TIMEOUT = 60.0
_OK, _ERROR, _STOP, _FRAMES = b"K", b"E", b"S", b"F"


class BusRecorder(can.Listener):
    """Thread-safe log writer for frames in both directions; the files are written by a process of its
    own (module docstring).

    Args:
        path: log file, or several (each gets every frame); the suffix selects the format (module
            docstring).
        channel: log channel number written for every frame.
    Raises:
        ValueError: unknown suffix (from :class:`can.Logger`); OSError: a file cannot be created;
        RuntimeError: the writer process did not start.
    Attributes:
        path: the first log file; paths: all of them.
        frames: number of frames handed to the writers so far.
        errors: number of frames the writers failed on (known once :meth:`stop` returned).
    """

    def __init__(self, path: str | Path | Sequence[str | Path], channel: int = 1):
        self.paths = [Path(p) for p in ([path] if isinstance(path, (str, Path)) else path)]
        if not self.paths:
            raise ValueError("BusRecorder needs at least one log file")
        self.path = self.paths[0]
        self.channel = channel
        self._lock = threading.Lock()
        self._batch: list[tuple] = []
        self._batch_since = 0.0
        self.frames = 0
        self.errors = 0
        mine, child = socket.socketpair()
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in sys.path if p))
        try:
            self._process = subprocess.Popen([sys.executable, "-m", __name__, str(child.fileno())],
                                             pass_fds=[child.fileno()], env=env)
        finally:
            child.close()
        self._conn = Connection(mine.detach())
        self._open = True
        try:
            self._conn.send_bytes(pickle.dumps(([str(p) for p in self.paths], channel)))
            answer = self._answer()
        except BaseException:
            self._abandon()
            raise
        if answer[:1] != _OK:
            self._abandon()
            raise pickle.loads(answer[1:])

    def on_message_received(self, msg: can.Message) -> None:
        """Record a received frame (called by the notifier thread). Never raises: a recorder whose
        writer process is gone counts the frames it cannot hand over in ``errors`` and logs once."""
        self._record((msg.timestamp, msg.arbitration_id, msg.dlc, bytes(msg.data or b""),
                      (msg.is_extended_id, msg.is_remote_frame, msg.is_error_frame, msg.is_rx, msg.is_fd,
                       msg.bitrate_switch, msg.error_state_indicator)))            # in _FLAGS order

    def on_frame(self, can_id: int, data: bytes, timestamp: float) -> None:
        """Record a received 11-bit data frame given as its values (the in-process bus's frame lane,
        :mod:`qomni.hil.virtual_bus`); the same record as :meth:`on_message_received` of its message."""
        self._record((timestamp, can_id, len(data), bytes(data), _RX_DATA_FRAME))

    def on_transmit_frame(self, can_id: int, data: bytes) -> None:
        """Record an 11-bit data frame this master sends, given as its values; stamped now."""
        self._record((time.time(), can_id, len(data), bytes(data), _TX_DATA_FRAME))

    def _record(self, frame: tuple) -> None:
        with self._lock:
            if not self._open:
                return
            batch = self._batch
            batch.append(frame)
            self.frames += 1
            if len(batch) == 1:
                self._batch_since = time.monotonic()
            elif len(batch) >= BATCH_FRAMES or time.monotonic() - self._batch_since > BATCH_AGE:
                self._hand_over()

    def on_transmit(self, msg: can.Message) -> None:
        """Record a frame this master sent; stamps it now and marks it as transmitted (``is_rx=False``)."""
        msg.timestamp = time.time()
        msg.is_rx = False
        self.on_message_received(msg)

    def stop(self) -> None:
        """Hand over the last frames, wait until every file is flushed and closed; idempotent, later
        frames are ignored."""
        with self._lock:
            if not self._open:
                return
            self._hand_over()
            self._open = False
            try:
                self._conn.send_bytes(_STOP)
                answer = self._answer()
                if answer[:1] == _OK:
                    self.errors += int.from_bytes(answer[1:], "little")
            except (OSError, EOFError, RuntimeError) as exc:
                logger.error("bus recorder %s: the writer process did not finish: %s", self.path, exc)
            finally:
                self._abandon()

    # -- internals ------------------------------------------------------------------------------
    def _hand_over(self) -> None:
        batch = self._batch
        if not batch:
            return
        self._batch = []
        try:
            self._conn.send_bytes(_FRAMES + pickle.dumps(batch, protocol=pickle.HIGHEST_PROTOCOL))
        except (OSError, ValueError):
            first = not self.errors
            self.errors += len(batch)
            if first:
                logger.error("bus recorder %s: the writer process is gone (exit code %s)", self.path,
                             self._process.poll())

    def _answer(self) -> bytes:
        if not self._conn.poll(WRITER_TIMEOUT):
            raise RuntimeError(f"bus recorder {self.path}: no answer from the writer process within "
                               f"{WRITER_TIMEOUT:.0f} s")
        return self._conn.recv_bytes()

    def _abandon(self) -> None:
        self._open = False
        self._conn.close()
        try:
            self._process.wait(WRITER_TIMEOUT)
        except subprocess.TimeoutExpired:
            self._process.kill()
            self._process.wait()


def _open_writers(paths: list[str]) -> list:
    writers = []
    try:
        for p in map(Path, paths):
            writers.append(can.BLFWriter(p) if p.suffix.lower() == ".blf" else can.Logger(p))
    except BaseException:
        for writer in writers:
            writer.stop()
        raise
    return writers


def _write_batch(writers: list, batch: list[tuple], channel: int) -> int:
    """Write one batch of frames with every writer; returns the frames a writer failed on."""
    errors = 0
    for timestamp, can_id, dlc, data, flags in batch:
        # All frames go to one log channel: python-can writers derive a number from the bus's channel
        # name (e.g. digits of a virtual channel), which need not fit the format.
        msg = can.Message(timestamp=timestamp, arbitration_id=can_id, data=data, dlc=dlc, channel=channel,
                          check=False, **dict(zip(_FLAGS, flags)))
        try:
            for writer in writers:
                writer.on_message_received(msg)
        except Exception:                          # noqa: BLE001 - counted, reported to the master on stop
            errors += 1
            if errors == 1:
                logger.exception("bus recorder: cannot write a frame")
    return errors


def _serve(conn: Connection) -> None:
    """The writer process: open the files, write the batches in order, close them on stop or EOF."""
    paths, channel = pickle.loads(conn.recv_bytes())
    try:
        writers = _open_writers(paths)
    except BaseException as exc:                   # noqa: BLE001 - raised by the master's constructor
        conn.send_bytes(_ERROR + pickle.dumps(exc))
        return
    conn.send_bytes(_OK)
    errors = 0
    try:
        while True:
            try:
                batch = conn.recv_bytes()
            except EOFError:                       # the master is gone: keep what was handed over
                return
            if batch == _STOP:
                break
            errors += _write_batch(writers, pickle.loads(batch[1:]), channel)
    finally:
        for writer in writers:
            writer.stop()
    conn.send_bytes(_OK + errors.to_bytes(8, "little"))


def replay(path: str | Path, bus: can.BusABC, *, realtime: bool = True, skip: float = 60.0,
           only: Callable[[can.Message], bool] | None = None) -> int:
    """Send every frame of a log onto ``bus``, in order.

    Args:
        path: log file (any format of :class:`can.LogReader`).
        bus: an open python-can bus.
        realtime: keep the recorded gaps between frames (:class:`can.MessageSync`); False: as fast as
            the bus takes them.
        skip: s, recorded gaps longer than this are shortened to it (idle phases).
        only: optional filter; frames for which it returns False are not sent.
    Returns:
        Number of frames sent.
    Raises:
        FileNotFoundError: no such log. ValueError: unknown log format. can.CanError: the bus refused a
            frame.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"log file {path} does not exist")
    reader = can.LogReader(str(path))
    frames = can.MessageSync(reader, timestamps=True, skip=skip) if realtime else reader
    sent = 0
    for msg in frames:
        if msg.is_error_frame or (only is not None and not only(msg)):
            continue
        msg.channel = None
        bus.send(msg)
        sent += 1
    return sent


_MASTER_FUNCTIONS = {0x0, 0x4, 0x6, 0x8, 0xA, 0xC}      # NMT, RPDO1…4, SDO request (COB-ID >> 7)


def sent_by_master(msg) -> bool:
    """Whether a frame is the master's in the CiA 301 pre-defined connection set (§7.3.3): NMT, SYNC,
    RPDOs and SDO requests (11-bit identifiers only)."""
    cob = msg.arbitration_id
    return not msg.is_extended_id and (cob == 0x80 or (cob >> 7) in _MASTER_FUNCTIONS)


if __name__ == "__main__":
    _serve(Connection(int(sys.argv[1])))
