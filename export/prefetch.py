"""Batches assembled ahead of the step, in background threads (``--workers N``).

Building a batch (slicing frames, shifting feet, targets, pinning for a GPU)
is numpy and memcpy work that releases the GIL, so threads overlap it with
the step running on the device. The batches come back in plan order, and
each is a pure function of its planned chunks, so prefetching changes no
number: a run with 0 workers and one with 4 are bit-identical.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Generator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from typing import TypeVar

Item = TypeVar("Item")
Built = TypeVar("Built")

# Batches built ahead per worker: enough to cover a slow batch, few enough to
# keep memory small (a batch of the paper's size is ~15 MB of frames).
AHEAD_PER_WORKER = 2


def prefetched(
    items: Sequence[Item], build: Callable[[Item], Built], workers: int
) -> Generator[Built, None, None]:
    """``build(item)`` for each item in order; ``workers`` threads run ahead (0: inline)."""
    if workers <= 0:
        for item in items:
            yield build(item)
        return
    ahead = workers * AHEAD_PER_WORKER
    pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="scotti-batches")
    pending: deque[Future[Built]] = deque()
    try:
        queued = 0
        while queued < len(items) or pending:
            while queued < len(items) and len(pending) < ahead:
                pending.append(pool.submit(build, items[queued]))
                queued += 1
            yield pending.popleft().result()
    finally:
        # Stopped early (time is up, an error): drop what was queued, do not wait for it.
        for future in pending:
            future.cancel()
        pool.shutdown(wait=True, cancel_futures=True)
