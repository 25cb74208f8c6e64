"""The shared waits: backoff delays and "until this event or that long"."""

from __future__ import annotations

import asyncio
import time

import pytest
from scotti.daemon.waiting import Backoff, wait_event


def test_wait_event_returns_at_once_when_set_and_false_after_the_timeout() -> None:
    async def body() -> tuple[bool, float, bool, float]:
        event = asyncio.Event()
        start = time.monotonic()
        timed_out = await wait_event(event, 0.05)
        waited = time.monotonic() - start
        asyncio.get_running_loop().call_later(0.01, event.set)
        start = time.monotonic()
        was_set = await wait_event(event, 10.0)
        return timed_out, waited, was_set, time.monotonic() - start

    timed_out, waited, was_set, took = asyncio.run(body())
    assert timed_out is False
    assert waited >= 0.04
    assert was_set is True
    assert took < 5.0


def test_a_cancel_is_not_swallowed_when_the_event_is_set_at_the_same_moment() -> None:
    async def body() -> None:
        event = asyncio.Event()
        task = asyncio.create_task(wait_event(event, 10.0))
        await asyncio.sleep(0)  # the task waits on the event
        event.set()  # its waiter is woken...
        task.cancel()  # ...and cancelled in the same loop turn
        with pytest.raises(asyncio.CancelledError):
            await task

    asyncio.run(body())


def test_backoff_without_jitter_doubles_up_to_the_cap() -> None:
    backoff = Backoff(0.25, cap_s=1.5, jitter=0.0)
    assert [backoff.next_delay() for _ in range(5)] == [0.25, 0.5, 1.0, 1.5, 1.5]
    backoff.reset()
    assert backoff.next_delay() == 0.25
