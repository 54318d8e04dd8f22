"""Busy polling: wait for a socket by polling it without blocking for a while, then block.

A process that blocks in ``select`` is woken by the kernel when data arrive; on a virtual machine whose
idle vCPU is handed back to the host, that wake-up can take milliseconds (measured on the 16-core
benchmark machine: an echo responder that does nothing but answer a SYNC, p99 2.7–3.1 ms, 3–3.5 % of its
answers later than T_s/2, docs/hil.md). Polling keeps the CPU and answers within the time of one poll,
at the price of a busy core: what Linux's ``SO_BUSY_POLL`` does for network drivers, here in user space
for the hub, the emulator's socketcand bus and the benchmark's master. Off by default; worth it only where
each polling process has a core of its own.

``busy`` is the longest time [s] one wait polls before it blocks for the rest of its timeout; a value at
least the SYNC period keeps a process polling from one SYNC to the next.
"""
from __future__ import annotations

import math
import select
import selectors
import time
from typing import Callable, TypeVar

T = TypeVar("T")


def check_busy(busy: float) -> float:
    """``busy`` as a float, or ValueError unless finite and ≥ 0."""
    busy = float(busy)
    if not (math.isfinite(busy) and busy >= 0.0):
        raise ValueError(f"busy-poll time must be a finite number of seconds ≥ 0, got {busy}")
    return busy


def poll_first(poll: Callable[[float | None], T], timeout: float | None, busy: float,
               ready: Callable[[T], bool]) -> T:
    """``poll(timeout)``, a wait with a timeout [s, None: forever], preceded by calls of ``poll(0)`` for up
    to ``busy`` s (at most the timeout) until one returns a result that is ``ready``."""
    if busy > 0.0 and (timeout is None or timeout > 0):
        clock = time.perf_counter
        start = clock()
        window = busy if timeout is None else min(busy, timeout)
        while True:
            result = poll(0.0)
            if ready(result):
                return result
            waited = clock() - start
            if waited >= window:
                break
        if timeout is not None:
            timeout = max(0.0, timeout - waited)
    return poll(timeout)


def poll_select(rlist: list, timeout: float | None, busy: float) -> list:
    """``select.select(rlist, [], [], timeout)[0]``, polling for up to ``busy`` s before it blocks."""
    return poll_first(lambda t: select.select(rlist, [], [], t)[0], timeout, busy, bool)


class PollingSelector(selectors.DefaultSelector):
    """The platform's default selector (epoll on Linux) whose ``select`` polls for up to ``busy`` s
    before it blocks: for ``asyncio.SelectorEventLoop(PollingSelector(busy))``."""

    def __init__(self, busy: float):
        super().__init__()
        self.busy = check_busy(busy)

    def select(self, timeout=None):
        return poll_first(super().select, timeout, self.busy, bool)
