"""Whole-bus recording: every frame the master receives and every frame it sends, to a log file.

A :class:`can.Listener` for the master's :class:`can.Notifier` (received frames) that the master also
calls for each frame it transmits (python-can buses do not hand own frames to notifiers). The writer
is :class:`can.BLFWriter` for ``.blf`` (Vector tools replay it); python-can's other log formats
(``.asc``, ``.log``, ``.csv``, …) are chosen by suffix through :class:`can.Logger`.
"""
from __future__ import annotations

import logging
import threading
import time
from pathlib import Path

import can

logger = logging.getLogger(__name__)


class BusRecorder(can.Listener):
    """Thread-safe log writer for frames in both directions.

    Args:
        path: log file; the suffix selects the format (``.blf`` → :class:`can.BLFWriter`).
        channel: log channel number written for every frame.
    Raises:
        ValueError: unknown suffix (from :class:`can.Logger`).
    Attributes:
        frames: number of frames written so far.
        errors: number of frames the writer failed on.
    """

    def __init__(self, path: str | Path, channel: int = 1):
        self.path = Path(path)
        self.channel = channel
        self._writer = can.BLFWriter(self.path) if self.path.suffix.lower() == ".blf" else can.Logger(self.path)
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
                self._writer.on_message_received(msg)
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
                self._writer.stop()
