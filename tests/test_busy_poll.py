"""qomni.hil.busy_poll: a wait polls without blocking for its window, then blocks for the rest of its
timeout; a ready answer ends it at once."""
from __future__ import annotations

import asyncio
import socket
import time

import pytest

from qomni.hil.busy_poll import PollingSelector, check_busy, poll_first, poll_select


def test_poll_first_polls_then_blocks_for_the_rest_of_the_timeout():
    calls, at = [], []

    def never(timeout):
        calls.append(timeout)
        at.append(time.perf_counter())
        if timeout:
            time.sleep(timeout)
        return None

    start = time.perf_counter()
    assert poll_first(never, 0.05, 0.01, lambda r: r is not None) is None
    elapsed = time.perf_counter() - start
    polls, last = calls[:-1], calls[-1]
    assert len(polls) > 1 and all(t == 0.0 for t in polls)          # non-blocking polls first
    assert at[-1] - start >= 0.01 and last <= 0.04                  # for the window at least
    # then the rest of the timeout, blocking (the window may overrun on a loaded machine: measured)
    assert last == pytest.approx(0.05 - (at[-1] - start), abs=0.005)
    assert 0.045 <= elapsed < 0.5
    calls.clear()
    assert poll_first(never, 0.02, 0.0, lambda r: r is not None) is None
    assert calls == [0.02]                                          # no window: block at once


def test_a_ready_answer_ends_the_poll_at_once():
    answers = iter([None, None, "frame"])
    assert poll_first(lambda t: next(answers), None, 1.0, lambda r: r is not None) == "frame"
    a, b = socket.socketpair()
    try:
        b.send(b"x")
        start = time.perf_counter()
        assert poll_select([a], 5.0, 1.0) == [a]
        assert time.perf_counter() - start < 0.5
        assert poll_select([b], 0.01, 0.005) == []
    finally:
        a.close()
        b.close()


def test_an_event_loop_on_a_polling_selector_serves_as_usual():
    loop = asyncio.SelectorEventLoop(PollingSelector(0.002))
    try:
        async def echo_once():
            a, b = socket.socketpair()
            reader, writer = await asyncio.open_connection(sock=a)
            b.send(b"hello")
            data = await asyncio.wait_for(reader.read(5), 2.0)
            writer.close()
            b.close()
            return data

        assert loop.run_until_complete(echo_once()) == b"hello"
        assert loop.run_until_complete(asyncio.sleep(0.01, "slept")) == "slept"
    finally:
        loop.close()


@pytest.mark.parametrize("bad", [-0.001, float("nan"), float("inf")])
def test_a_poll_window_must_be_finite_and_not_negative(bad):
    with pytest.raises(ValueError, match="busy-poll"):
        check_busy(bad)
    with pytest.raises(ValueError, match="busy-poll"):
        PollingSelector(bad)


def test_busy_polling_belongs_to_socketcand_buses():
    from qomni.hil.bus import open_bus

    with pytest.raises(ValueError, match="socketcand"):
        open_bus("virtual:busy-poll-test", busy_poll=0.001)
