"""Whole-bus recording: every frame the master receives and every frame it sends, to log files; and
replay of a log onto a bus.

A :class:`can.Listener` for the master's :class:`can.Notifier` (received frames) that the master also
calls for each frame it transmits (python-can buses do not hand own frames to notifiers). One recorder
writes one or several files at once; the suffix picks the format: :class:`can.BLFWriter` for ``.blf``
(Vector tools replay it), candump ``-L`` format for ``.log`` (:class:`can.CanutilsLogWriter`; can-utils'
``canplayer`` and ``log2asc`` read it), and python-can's other formats (``.asc``, ``.csv``, ``.trc``, …)
through :class:`can.Logger`.

:func:`replay` sends a recorded log onto a bus with its original timing (:class:`can.LogReader`,
:class:`can.MessageSync`).
"""
from __future__ import annotations

import logging
import threading
import time
from pathlib import Path
from typing import Callable, Sequence

import can

logger = logging.getLogger(__name__)


class BusRecorder(can.Listener):
    """Thread-safe log writer for frames in both directions.

    Args:
        path: log file, or several (each gets every frame); the suffix selects the format (module
            docstring).
        channel: log channel number written for every frame.
    Raises:
        ValueError: unknown suffix (from :class:`can.Logger`).
    Attributes:
        path: the first log file; paths: all of them.
        frames: number of frames written so far.
        errors: number of frames the writer failed on.
    """

    def __init__(self, path: str | Path | Sequence[str | Path], channel: int = 1):
        self.paths = [Path(p) for p in ([path] if isinstance(path, (str, Path)) else path)]
        if not self.paths:
            raise ValueError("BusRecorder needs at least one log file")
        self.path = self.paths[0]
        self.channel = channel
        self._writers = []
        try:
            for p in self.paths:
                self._writers.append(can.BLFWriter(p) if p.suffix.lower() == ".blf" else can.Logger(p))
        except BaseException:
            for writer in self._writers:
                writer.stop()
            raise
        self._lock = threading.Lock()
        self._open = True
        self.frames = 0
        self.errors = 0

    def on_message_received(self, msg: can.Message) -> None:
        """Record a received frame (called by the notifier thread). Never raises: a failing writer must
        not stop the master's reception; failures are counted in ``errors`` and logged once."""
        with self._lock:
            if not self._open:
                return
            # All frames go to one log channel: python-can writers derive a number from the bus's
            # channel name (e.g. digits of a virtual channel), which need not fit the format.
            original, msg.channel = msg.channel, self.channel
            try:
                for writer in self._writers:
                    writer.on_message_received(msg)
                self.frames += 1
            except Exception:                      # noqa: BLE001
                self.errors += 1
                if self.errors == 1:
                    logger.exception("bus recorder %s: cannot write a frame", self.path)
            finally:
                msg.channel = original

    def on_transmit(self, msg: can.Message) -> None:
        """Record a frame this master sent; stamps it now and marks it as transmitted (``is_rx=False``)."""
        msg.timestamp = time.time()
        msg.is_rx = False
        self.on_message_received(msg)

    def stop(self) -> None:
        """Flush and close the file; idempotent, later frames are ignored."""
        with self._lock:
            if self._open:
                self._open = False
                for writer in self._writers:
                    writer.stop()


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
