"""What the operating system can do for a real-time emulator process: CPU pinning, real-time priority, the
garbage collector kept off the cycle, and sleeping to absolute monotonic deadlines.

Linux calls (``os.sched_setaffinity``, ``os.sched_setscheduler`` with ``SCHED_FIFO``, man 7 sched). A
refusal is no error: each request returns the sentence that says what was (not) done and why, so the
caller prints it; a real-time priority normally needs root or ``CAP_SYS_NICE`` (``EPERM`` otherwise;
``RLIMIT_RTPRIO`` in /etc/security/limits.conf grants it to a user).
"""
from __future__ import annotations

import errno
import gc
import os
import time
from typing import Iterable


class RealtimeError(ValueError):
    """A request that cannot be right on any machine: an empty or negative CPU set, a priority outside
    the scheduler's range."""


def parse_cpus(text: str) -> set[int]:
    """``"2,3"`` or ``"0-3,6"`` → {2, 3} / {0, 1, 2, 3, 6}. Raises RealtimeError on anything else."""
    cpus: set[int] = set()
    for part in text.split(","):
        part = part.strip()
        low, sep, high = part.partition("-")
        try:
            first, last = int(low), int(high if sep else low)
        except ValueError:
            raise RealtimeError(f"CPU list {text!r}: '{part}' is not a number or a range like 2-3") from None
        if first < 0 or last < first:
            raise RealtimeError(f"CPU list {text!r}: '{part}' is not a range of CPU numbers ≥ 0")
        cpus.update(range(first, last + 1))
    return cpus


def pin_cpus(cpus: Iterable[int]) -> str:
    """Restrict this process (every thread started later inherits it) to ``cpus``.

    Returns:
        The sentence to print: pinned, or why not (CPU not available to this process, no such call).
    Raises:
        RealtimeError: empty set.
    """
    wanted = sorted(set(cpus))
    if not wanted:
        raise RealtimeError("the CPU set is empty")
    if not hasattr(os, "sched_setaffinity"):
        return "CPU pinning is not available on this operating system; running unpinned"
    available = sorted(os.sched_getaffinity(0))
    missing = [c for c in wanted if c not in available]
    if missing:
        return (f"CPU(s) {missing} not available to this process (allowed: {available}); running unpinned")
    os.sched_setaffinity(0, wanted)
    return f"pinned to CPU(s) {wanted}"


def set_realtime_priority(priority: int) -> str:
    """Run this process under ``SCHED_FIFO`` at ``priority`` (threads started later inherit it).

    Returns:
        The sentence to print: done, or why not (EPERM: the user may not; no such scheduler).
    Raises:
        RealtimeError: priority outside ``sched_get_priority_min/max(SCHED_FIFO)`` (1…99 on Linux).
    """
    if not hasattr(os, "sched_setscheduler"):
        return "real-time scheduling is not available on this operating system; normal priority"
    low, high = os.sched_get_priority_min(os.SCHED_FIFO), os.sched_get_priority_max(os.SCHED_FIFO)
    if not low <= priority <= high:
        raise RealtimeError(f"real-time priority must be {low}…{high}, got {priority}")
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except PermissionError:
        return (f"SCHED_FIFO priority {priority} refused (EPERM): this user may not raise real-time priority; "
                "run as root, grant CAP_SYS_NICE (setcap cap_sys_nice+ep on the Python binary) or an "
                "rtprio limit in /etc/security/limits.conf; running at normal priority")
    except OSError as exc:
        if exc.errno == errno.EINVAL:
            return f"SCHED_FIFO priority {priority} refused by the kernel (EINVAL); running at normal priority"
        raise
    return f"SCHED_FIFO priority {priority}"


class QuietCollector:
    """The garbage collector kept off the cycle: on :meth:`start` every object alive is frozen (never
    scanned again) and automatic collection is disabled; the owner calls :meth:`after_cycle` where a
    cycle's work is done, which collects the young generation every ``every`` cycles there and only
    there. :meth:`stop` restores the collector as it was.

    Args:
        every: cycles between young-generation collections (a cycle allocates a few hundred objects).
    """

    def __init__(self, every: int = 50):
        self.every = int(every)
        self._count = 0
        self._was_enabled: bool | None = None

    def start(self) -> None:
        self._was_enabled = gc.isenabled()
        gc.collect()
        gc.freeze()
        gc.disable()

    def after_cycle(self) -> None:
        if self._was_enabled is None:
            return
        self._count += 1
        if self._count >= self.every:
            self._count = 0
            gc.collect(1)

    def stop(self) -> None:
        if self._was_enabled is None:
            return
        gc.unfreeze()
        if self._was_enabled:
            gc.enable()
        self._was_enabled = None


def sleep_until(deadline: float) -> None:
    """Sleep until ``time.monotonic()`` reaches ``deadline`` [s]; returns at once if it has passed.

    An absolute deadline (tick k at t₀ + k·T_s) does not drift with the time spent between sleeps;
    CPython sleeps with ``clock_nanosleep(CLOCK_MONOTONIC)`` on Linux.
    """
    delay = deadline - time.monotonic()
    if delay > 0:
        time.sleep(delay)
