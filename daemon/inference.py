"""Inference on one worker thread; the event loop never waits on it.

The loop ``submit``s paired frames; one dedicated thread runs them through the
window in order and hands each result back with ``loop.call_soon_threadsafe``.

When inference falls behind (more than ``max_queue`` frames waiting), the
oldest waiting frame is dropped and counted, and the window starts over before
the next frame it runs. Why a restart and not just a skip: the embedding cache
must hold the last T-1 frames at 16 Hz; a frame missing from it would put every
later frame at the wrong time offset for the next T frames, which is a quiet
lie. A restart is loud instead: the state says "warming", ``dropped_frames``
and ``window_restarts`` count it, and the predictions that do come are right.
A source that can wait (replay) never reaches this: the pipeline waits for room.
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from scotti.daemon.pairing import PairedFrame
from scotti.daemon.window import Window, WindowOutput

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class InferenceJob:
    seq: int  # host-side count of paired frames since start
    frame: PairedFrame


@dataclass(frozen=True)
class InferenceResult:
    job: InferenceJob
    output: WindowOutput | None  # None when the model failed on this frame (see error)
    inference_ms: float
    restarted: bool  # the window started over before this frame
    error: str | None = None


class InferenceWorker:
    """One thread, one window; ``on_result`` is called on the event loop thread."""

    def __init__(
        self,
        window: Window,
        on_result: Callable[[InferenceResult], None],
        *,
        max_queue: int = 16,
    ) -> None:
        self.window = window
        self.max_queue = max_queue
        self._on_result = on_result
        self._loop: asyncio.AbstractEventLoop | None = None
        self._queue: deque[InferenceJob] = deque()
        self._cond = threading.Condition()
        self._restart_pending = False
        self._stopping = False
        self._thread: threading.Thread | None = None
        # Loop-thread bookkeeping: jobs submitted whose result has not been delivered yet.
        self._in_flight = 0
        self._changed = asyncio.Event()

    @property
    def in_flight(self) -> int:
        """Jobs waiting or running (read on the loop thread)."""
        return self._in_flight

    def start(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._thread = threading.Thread(target=self._run, name="scotti-inference", daemon=True)
        self._thread.start()

    def submit(self, job: InferenceJob) -> int:
        """Queue a frame without waiting; returns how many old frames were dropped (0 or 1)."""
        dropped = 0
        with self._cond:
            if len(self._queue) >= self.max_queue:
                self._queue.popleft()
                self._restart_pending = True  # the cache would miss that frame
                dropped = 1
            self._queue.append(job)
            self._cond.notify()
        self._in_flight += 1 - dropped
        return dropped

    def restart_window(self) -> None:
        """Start the window over before the next frame (a reconnect)."""
        with self._cond:
            self._restart_pending = True

    async def wait_below(self, depth: int) -> None:
        """Wait until fewer than ``depth`` jobs are in flight (backpressure, draining)."""
        while self._in_flight >= max(depth, 1):
            self._changed.clear()
            await self._changed.wait()

    async def stop(self) -> None:
        """Stop after the frame being run (if any); waiting frames are not run."""
        with self._cond:
            self._stopping = True
            self._cond.notify()
        if self._thread is not None:
            await asyncio.to_thread(self._thread.join, 5.0)
            self._thread = None

    # --- the worker thread ------------------------------------------------------

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._queue and not self._stopping:
                    self._cond.wait()
                if self._stopping:
                    return
                job = self._queue.popleft()
                restart = self._restart_pending or job.frame.restart
                self._restart_pending = False
            if restart:
                self.window.restart()
            start = time.perf_counter()
            try:
                output: WindowOutput | None = self.window.push(job.frame.counts)
                error = None
            except Exception as exc:  # a model failure must not kill the worker
                log.debug("inference failed on frame %d", job.seq, exc_info=True)
                output, error = None, f"{type(exc).__name__}: {exc}"
            ms = (time.perf_counter() - start) * 1e3
            result = InferenceResult(job, output, ms, restart, error)
            assert self._loop is not None
            try:
                self._loop.call_soon_threadsafe(self._deliver, result)
            except RuntimeError:
                return  # the loop is closed: nobody is listening any more

    def _deliver(self, result: InferenceResult) -> None:
        self._in_flight -= 1
        self._changed.set()
        self._on_result(result)
