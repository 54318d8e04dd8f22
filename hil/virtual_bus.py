"""The in-process CAN bus of the lock-step vehicle: python-can's ``virtual`` bus with inline delivery.

:class:`InlineVirtualBus` is a :class:`can.interfaces.virtual.VirtualBus` (same channel registry, so it
sees, and is seen by, every plain ``virtual`` bus of the process on the same channel) that differs in two
ways on the hot path:

* **One cheap copy per receiver.** A sent frame reaches each receiver as its own :class:`can.Message`
  built slot by slot (python-can's ``virtual`` deep-copies the message per receiver, ~15 µs each).
* **Inline delivery.** A bus whose owner called :meth:`InlineVirtualBus.deliver_inline` gets its frames
  handed to its listeners in the sending thread, instead of through a queue and the receiving
  :class:`can.Notifier`'s thread. A lock-step SYNC then runs master → devices → master in one thread:
  no thread hop, no waiting for the GIL, no lock hand-over per frame.

Order: every receiver sees the frames in the order they were sent, causes before effects. A frame sent
from inside a listener (a device answering a SYNC) is queued in the sending thread and delivered after
the frame being delivered has reached every receiver, so a TPDO never overtakes its SYNC anywhere
(deliveries of one thread are first in, first out). Consequence for listeners: a listener must not
block waiting for the answer to a frame it sent itself (the answer comes after it returns); the CANopen
devices and the client's listeners never do.

Frames are delivered to plain queues (``virtual`` buses, and inline buses not attached) before the
inline listeners of the same frame run, so a passive observer on the channel sees the SYNC before the
TPDOs it causes.
"""
from __future__ import annotations

import logging
import queue
import threading
import time
from typing import Callable, Iterable

import can
from can.interfaces.virtual import VirtualBus, channels_lock

logger = logging.getLogger(__name__)

_Message = can.Message
_new = _Message.__new__
_local = threading.local()


def copy_message(msg: can.Message, timestamp: float, channel) -> can.Message:
    """A received copy of ``msg``: same frame, ``timestamp`` [s, time.time()], ``channel``, ``is_rx``."""
    out = _new(_Message)
    out.timestamp = timestamp
    out.arbitration_id = msg.arbitration_id
    out.is_extended_id = msg.is_extended_id
    out.is_remote_frame = msg.is_remote_frame
    out.is_error_frame = msg.is_error_frame
    out.channel = channel
    out.dlc = msg.dlc
    out.data = bytearray(msg.data)
    out.is_fd = msg.is_fd
    out.is_rx = True
    out.bitrate_switch = msg.bitrate_switch
    out.error_state_indicator = msg.error_state_indicator
    return out


def data_frame(can_id: int, data: bytes) -> can.Message:
    """An 11-bit data frame ``can_id`` (≤ 0x7FF) carrying ``data`` (≤ 8 bytes), built without python-can's
    argument checks: for senders whose frames are valid by construction (PDOs from a compiled codec)."""
    out = _new(_Message)
    out.timestamp = 0.0
    out.arbitration_id = can_id
    out.is_extended_id = out.is_remote_frame = out.is_error_frame = False
    out.channel = None
    out.dlc = len(data)
    out.data = bytearray(data)
    out.is_fd = out.is_rx = out.bitrate_switch = out.error_state_indicator = False
    return out


class _Inbox(queue.Queue):
    """The receive queue of an :class:`InlineVirtualBus`; ``deliver`` set = listeners called inline."""

    deliver: Callable[[can.Message], None] | None = None

    def put(self, item, block=True, timeout=None):         # a plain VirtualBus sender lands here
        deliver = self.deliver
        if deliver is None:
            super().put(item, block, timeout)
        else:
            _dispatch([(deliver, item)])


def _dispatch(items: list) -> None:
    """Run each ``(deliver, msg)`` now if this thread is not delivering already, else after the frames
    already queued in this thread: one first-in, first-out order per thread for every receiver."""
    pending = getattr(_local, "pending", None)
    if pending is not None:
        pending.extend(items)
        return
    pending = _local.pending = items
    try:
        i = 0
        while i < len(pending):                         # grows while listeners send
            _call(*pending[i])
            i += 1
    finally:
        _local.pending = None


def _call(deliver: Callable[[can.Message], None], msg: can.Message) -> None:
    try:
        deliver(msg)
    except Exception:                                   # noqa: BLE001 - a Notifier would log it too
        logger.exception("listener failed on frame 0x%X", msg.arbitration_id)


class InlineVirtualBus(VirtualBus):
    """python-can ``virtual`` bus with cheap copies and optional inline delivery (module docstring).

    Args:
        channel: channel name; every ``virtual`` bus of this process on it is a peer.
        kwargs: as :class:`can.interfaces.virtual.VirtualBus` (``receive_own_messages``, ``preserve_timestamps``…).
    """

    def __init__(self, channel="channel-0", **kwargs):
        super().__init__(channel, **kwargs)
        with channels_lock:
            index = next(i for i, q in enumerate(self.channel) if q is self.queue)
            self.queue = self.channel[index] = _Inbox()

    def deliver_inline(self, listeners: Iterable[can.Listener]) -> None:
        """From now on hand received frames to ``listeners`` in the sending thread (no queue, the
        Notifier reading this bus stays idle). Frames already queued are still read by the Notifier."""
        targets = tuple(listeners)

        def deliver(msg: can.Message) -> None:
            for listener in targets:
                listener.on_message_received(msg)

        self.queue.deliver = deliver

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._check_if_open()
        timestamp = msg.timestamp if self.preserve_timestamps else time.time()
        channel, own = self.channel_id, self.queue
        inline = []
        for inbox in tuple(self.channel):
            if inbox is own and not self.receive_own_messages:
                continue
            copy = copy_message(msg, timestamp, channel)
            if inbox is own:
                copy.is_rx = False
            deliver = getattr(inbox, "deliver", None)
            if deliver is None:
                try:
                    inbox.put(copy, block=True, timeout=timeout)
                except queue.Full:
                    raise can.CanOperationError("Could not send message to one or more recipients") from None
            else:
                inline.append((deliver, copy))
        if inline:
            _dispatch(inline)

    def shutdown(self) -> None:
        self.queue.deliver = None
        super().shutdown()


def attach_inline(network) -> bool:
    """Deliver the frames of a connected :class:`canopen.Network` inline if its bus is an
    :class:`InlineVirtualBus` (else nothing changes). Returns whether it is."""
    bus = network.bus
    if not isinstance(bus, InlineVirtualBus):
        return False
    bus.deliver_inline(network.listeners)
    return True
