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

**The frame lane.** An 11-bit data frame (the PDOs, SYNC, NMT, SDO of CiA 301) needs no
:class:`can.Message` on its way between two inline networks. A listener with an
``on_frame(can_id, data, timestamp)`` method (the devices' listener, the bus recorder), and canopen's
own ``MessageListener`` (whose work is ``network.notify(can_id, data, timestamp)``), takes the frame as
those three values; :meth:`InlineVirtualBus.send_frame` sends one without building a message where no
receiver needs it. A receiver with any other listener, and every plain ``virtual`` bus, still gets its
own :class:`can.Message` copy. Same frames, same order, same time stamps either way.
"""
from __future__ import annotations

import logging
import queue
import threading
import time
from typing import Callable, Iterable

import can
from can.interfaces.virtual import VirtualBus, channels_lock
from canopen.network import MessageListener

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
    """The receive queue of an :class:`InlineVirtualBus`; ``deliver`` set = listeners called inline
    with a message, ``deliver_frame`` set = they also take a frame as (can_id, data, timestamp)."""

    deliver: Callable[[can.Message], None] | None = None
    deliver_frame: Callable[[int, bytes, float], None] | None = None

    def put(self, item, block=True, timeout=None):         # a plain VirtualBus sender lands here
        deliver = self.deliver
        if deliver is None:
            super().put(item, block, timeout)
        else:
            _dispatch([(deliver, (item,))])


def _dispatch(items: list) -> None:
    """Run each ``(function, args)`` now if this thread is not delivering already, else after the frames
    already queued in this thread: one first-in, first-out order per thread for every receiver."""
    pending = getattr(_local, "pending", None)
    if pending is not None:
        pending.extend(items)
        return
    pending = _local.pending = items
    try:
        i = 0
        while i < len(pending):                         # grows while listeners send
            function, args = pending[i]
            try:
                function(*args)
            except Exception:                           # noqa: BLE001 - a Notifier would log it too
                first = args[0]
                logger.exception("listener failed on frame 0x%X",
                                 first if isinstance(first, int) else first.arbitration_id)
            i += 1
    finally:
        _local.pending = None


def _frame_entry(listener: can.Listener) -> Callable[[int, bytes, float], None] | None:
    """How ``listener`` takes a frame as (can_id, data, timestamp), or None if it needs a message."""
    on_frame = getattr(listener, "on_frame", None)
    if on_frame is not None:
        return on_frame
    if type(listener) is MessageListener:
        notify = listener.network.notify

        def to_network(can_id: int, data: bytes, timestamp: float) -> None:
            try:
                notify(can_id, data, timestamp)
            except Exception as exc:                    # noqa: BLE001 - as canopen's MessageListener
                logger.error(str(exc))

        return to_network
    return None


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

        entries = [_frame_entry(listener) for listener in targets]
        deliver_frame = None
        if entries and None not in entries:
            if len(entries) == 1:
                deliver_frame = entries[0]
            else:
                def deliver_frame(can_id: int, data: bytes, timestamp: float) -> None:
                    for entry in entries:
                        entry(can_id, data, timestamp)
        self.queue.deliver_frame = deliver_frame
        self.queue.deliver = deliver

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._check_if_open()
        timestamp = msg.timestamp if self.preserve_timestamps else time.time()
        if (msg.arbitration_id <= 0x7FF and not (msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame
                                                 or msg.is_fd) and msg.dlc == len(msg.data) <= 8):
            self._send(msg.arbitration_id, bytes(msg.data), timestamp, msg, timeout)
        else:
            self._send(msg.arbitration_id, None, timestamp, msg, timeout)

    def send_frame(self, can_id: int, data: bytes) -> None:
        """Send the 11-bit data frame ``can_id`` (≤ 0x7FF) with ``data`` (bytes, ≤ 8): what
        ``send(data_frame(can_id, data))`` does, without a message for receivers that take frames
        (module docstring). For senders whose frames are valid by construction; nothing is checked."""
        self._check_if_open()
        self._send(can_id, data, 0.0 if self.preserve_timestamps else time.time(), None, None)

    def _send(self, can_id: int, data: bytes | None, timestamp: float, msg: can.Message | None,
              timeout: float | None) -> None:
        """Deliver to every receiver on the channel; ``data`` None: the frame needs its message ``msg``."""
        channel, own = self.channel_id, self.queue
        inline = []
        for inbox in tuple(self.channel):
            if inbox is own and not self.receive_own_messages:
                continue
            if data is not None and inbox is not own:
                deliver_frame = getattr(inbox, "deliver_frame", None)
                if deliver_frame is not None:
                    inline.append((deliver_frame, (can_id, data, timestamp)))
                    continue
            if msg is None:
                msg = data_frame(can_id, data)
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
                inline.append((deliver, (copy,)))
        if inline:
            _dispatch(inline)

    def shutdown(self) -> None:
        self.queue.deliver = self.queue.deliver_frame = None
        super().shutdown()


def attach_inline(network) -> bool:
    """Deliver the frames of a connected :class:`canopen.Network` inline if its bus is an
    :class:`InlineVirtualBus` (else nothing changes). Returns whether it is."""
    bus = network.bus
    if not isinstance(bus, InlineVirtualBus):
        return False
    bus.deliver_inline(network.listeners)
    return True
