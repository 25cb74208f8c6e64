"""A serial port's bytes as they come, read straight from its descriptor.

pyserial opens and sets up the port (the exclusive lock, the baud rate, raw mode,
the input flushed); after that, each time the event loop finds the descriptor
readable, one ``os.read`` takes everything the port holds. That is what the
loop's wake-up costs and no more: pyserial's own read adds two ``select`` calls
and a Python loop to every read, and serial_asyncio_fast's transport reads at
most 1 KiB a wake-up (a foot frame's 4 packets are about 1.5 KB: two wake-ups).

A read that waits ``stall_s`` without a byte ends as stalled, found by one timer
that looks every ``stall_s`` or so rather than a timeout armed and disarmed
around every read (about 4 us a read).
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import time
from collections import deque
from typing import Final

import serial

READ_MAX: Final = 1 << 16  # bytes taken from the port per wake-up, at most
HELD_MAX: Final = 1 << 16  # bytes held for a reader that is behind; past it the port
# is not read until the reader catches up (the kernel's buffer, then the board, wait)
STALLED: Final = "stalled"  # what ``read`` says when no byte came for ``stall_s``
# pyserial's words for a port that went away, kept so that status reads as it always did
GONE: Final = (
    "device reports readiness to read but returned no data "
    "(device disconnected or multiple access on port?)"
)


class PortReader:
    """``await read()``: (host monotonic ns the bytes were read, bytes), or why no more
    will come (``STALLED``, ``"read failed: ..."``, ``GONE``). ``close()`` closes the
    port (and releases its lock) at once."""

    def __init__(self, port: serial.Serial, stall_s: float) -> None:
        self._loop = asyncio.get_running_loop()
        self._port = port
        self._fd: int = port.fileno()
        self._stall_s = stall_s
        self._chunks: deque[tuple[int, bytes]] = deque()
        self._held = 0  # bytes in _chunks
        self._end: str | None = None  # why no more bytes will come (after those held)
        self._waiter: asyncio.Future[None] | None = None
        self._waiting_since: float | None = None  # loop time a read began waiting, if one is
        self._reading = True  # the loop watches the descriptor
        self._loop.add_reader(self._fd, self._readable)
        self._timer = self._loop.call_later(stall_s, self._look)

    async def read(self) -> tuple[int, bytes] | str:
        while not self._chunks:
            if self._end is not None:
                return self._end
            self._waiter = self._loop.create_future()
            self._waiting_since = self._loop.time()
            try:
                await self._waiter
            finally:
                self._waiter = self._waiting_since = None
        chunk = self._chunks.popleft()
        self._held -= len(chunk[1])
        if not self._reading and self._end is None and self._held < HELD_MAX // 2:
            self._loop.add_reader(self._fd, self._readable)
            self._reading = True
        return chunk

    def close(self) -> None:
        self._timer.cancel()
        self._stop_reading()
        with contextlib.suppress(Exception):  # it may be gone already (unplugged)
            self._port.close()

    def _readable(self) -> None:
        try:
            data = os.read(self._fd, READ_MAX)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:
            self._finish(f"read failed: {exc}")
            return
        if not data:
            self._finish(GONE)
            return
        self._chunks.append((time.monotonic_ns(), data))
        self._held += len(data)
        if self._held >= HELD_MAX:
            self._stop_reading()
        self._wake()

    def _look(self) -> None:
        if self._end is not None:
            return
        since, now = self._waiting_since, self._loop.time()
        if since is not None and now - since >= self._stall_s:
            self._finish(STALLED)
            return
        due = self._stall_s if since is None else since + self._stall_s - now
        self._timer = self._loop.call_later(due, self._look)

    def _finish(self, why: str) -> None:
        if self._end is None:
            self._end = why
        self._stop_reading()
        self._wake()

    def _stop_reading(self) -> None:
        if self._reading:
            self._loop.remove_reader(self._fd)
            self._reading = False

    def _wake(self) -> None:
        if self._waiter is not None and not self._waiter.done():
            self._waiter.set_result(None)
