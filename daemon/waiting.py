"""Waiting on the event loop: retry delays, and "until this event or that long".

Shared by the serial source, the MQTT publisher and the timers (health,
watchdog, viewer), so that every retry backs off the same way and every
timed wait uses ``asyncio.timeout``: on Python 3.11 ``asyncio.wait_for`` can
swallow a cancel that lands as its awaitable completes, and a loop built on it
may then never stop.
"""

from __future__ import annotations

import asyncio
import contextlib
import random
from dataclasses import dataclass


@dataclass
class Backoff:
    """Exponential backoff, capped, with jitter (so many daemons do not retry in step)."""

    initial_s: float = 0.05
    cap_s: float = 5.0
    factor: float = 2.0
    jitter: float = 0.5  # each delay is shortened by up to this fraction at random
    attempt: int = 0

    def next_delay(self) -> float:
        delay = min(self.cap_s, self.initial_s * self.factor**self.attempt)
        self.attempt += 1
        return delay * (1.0 - self.jitter * random.random())

    def reset(self) -> None:
        self.attempt = 0


async def wait_event(event: asyncio.Event, timeout_s: float) -> bool:
    """Wait until ``event`` is set or ``timeout_s`` has passed; True if it is set."""
    with contextlib.suppress(TimeoutError):
        async with asyncio.timeout(timeout_s):
            await event.wait()
    return event.is_set()
