"""Inference on one worker thread shared by every device; the event loop never waits on it.

Each device (one insole pair) has a lane: the loop ``submit``s its paired
frames there. One dedicated thread, the engine's, takes the oldest frame of
every lane that has one and runs them all in ONE call of the model's step
graph (its batch axis; more than ``max_batch`` ready frames go in several calls
of at most that many: per frame, the step costs least at a few frames per call,
``bench --step-batches``), then hands the results back to the lanes' loop with
one ``loop.call_soon_threadsafe``. A lane gives at most one frame per turn: a
window's next step needs the embedding its previous step made. The engine
never waits for a lane: a device whose foot is silent or whose receiver is
unplugged simply has nothing ready, and the others go without it. With
``batch=False`` the same thread runs one call per lane instead (the bench
compares the two).

When inference falls behind (more than ``max_queue`` frames waiting in a
lane), the lane's oldest waiting frame is dropped and counted, and its window
starts over before the next frame it runs. Why a restart and not just a skip:
the embedding cache must hold the last T-1 frames at 16 Hz; a frame missing
from it would put every later frame at the wrong time offset for the next T
frames, which is a quiet lie. A restart is loud instead: the state says
"warming", ``dropped_frames`` and ``window_restarts`` count it, and the
predictions that do come are right. A source that can wait (replay) never
reaches this: the pipeline waits for room.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from scotti.daemon.inference.window import Window, WindowOutput
from scotti.firmware_protocol.pairing import PairedFrame
from scotti.models.contract import FRAME_RATE_HZ

PERIOD_S = 1.0 / FRAME_RATE_HZ  # a lane's next frame is due this long after its last

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class InferenceJob:
    seq: int  # host-side count of paired frames since start
    frame: PairedFrame


@dataclass(frozen=True)
class InferenceResult:
    job: InferenceJob
    output: WindowOutput | None  # None when the model failed on this frame (see error)
    inference_ms: float  # the model call that ran this frame (shared by its batch)
    restarted: bool  # the window started over before this frame
    error: str | None = None
    batch_size: int = 1  # frames of all devices run in that one call


class InferenceLane:
    """One device's queue into the engine; ``on_result`` runs on that device's loop."""

    def __init__(
        self,
        engine: InferenceEngine,
        window: Window,
        on_result: Callable[[InferenceResult], None],
        max_queue: int,
    ) -> None:
        self.engine = engine
        self.window = window
        self.max_queue = max_queue
        self._on_result = on_result
        self._loop: asyncio.AbstractEventLoop | None = None
        # Guarded by the engine's condition: shared with the engine's thread.
        self._queue: deque[InferenceJob] = deque()
        self._restart_pending = False
        self._last_submit = -1.0  # monotonic time of the last submit (-1: none yet)
        # Loop-thread bookkeeping: jobs submitted whose result has not been delivered yet.
        self._in_flight = 0
        self._changed = asyncio.Event()

    @property
    def loop(self) -> asyncio.AbstractEventLoop | None:
        """The loop results are delivered on (None until ``start``)."""
        return self._loop

    @property
    def in_flight(self) -> int:
        """Jobs waiting or running (read on the loop thread)."""
        return self._in_flight

    def start(self) -> None:
        """Join the engine (and start it, when this lane's owner is the only user)."""
        self._loop = asyncio.get_running_loop()
        self.engine.attach(self)

    def submit(self, job: InferenceJob) -> int:
        """Queue a frame without waiting; returns how many old frames were dropped (0 or 1)."""
        dropped = 0
        with self.engine.cond:
            if len(self._queue) >= self.max_queue:
                self._queue.popleft()
                self._restart_pending = True  # the cache would miss that frame
                dropped = 1
            self._queue.append(job)
            self._last_submit = time.monotonic()
            self.engine.cond.notify()
        self._in_flight += 1 - dropped
        return dropped

    async def wait_below(self, depth: int) -> None:
        """Wait until fewer than ``depth`` jobs are in flight (backpressure, draining)."""
        while self._in_flight >= max(depth, 1):
            self._changed.clear()
            await self._changed.wait()

    async def stop(self) -> None:
        """Leave the engine after the turn being run (if any); waiting frames are not run."""
        await self.engine.detach(self)

    # --- called by the engine ------------------------------------------------------

    @property
    def has_waiting(self) -> bool:
        """A frame waits (the caller holds the engine's condition)."""
        return bool(self._queue)

    def take(self) -> tuple[InferenceJob, bool] | None:
        """(oldest job, restart first?) or None; the caller holds the engine's condition."""
        if not self._queue:
            return None
        job = self._queue.popleft()
        restart = self._restart_pending or job.frame.restart
        self._restart_pending = False
        return job, restart

    def due_within(self, now: float, horizon_s: float) -> bool:
        """Is this lane's next frame due within ``horizon_s`` of ``now`` (or that late)?
        A silent lane (unplugged, a foot gone) is not: its last frame is long past.
        The caller holds the engine's condition."""
        if self._last_submit < 0:
            return False
        return abs(self._last_submit + PERIOD_S - now) <= horizon_s

    def discard_waiting(self) -> None:
        """Drop the frames not yet taken; the caller holds the engine's condition."""
        self._queue.clear()

    def deliver(self, result: InferenceResult) -> None:
        """On the lane's loop: one result to the lane's owner."""
        self._in_flight -= 1
        self._changed.set()
        self._on_result(result)


class InferenceEngine:
    """One thread running the windows of every attached lane, batched by default.

    ``owned``: stop the thread when the last lane leaves (a pipeline that made its
    own engine); a shared engine is started and stopped by the daemon.
    """

    def __init__(
        self,
        *,
        batch: bool = True,
        max_batch: int = 8,
        gather_ms: float = 0.0,
        owned: bool = False,
    ) -> None:
        self.batch = batch
        self.max_batch = max_batch if batch else 1
        # Up to this long for the frames of other lanes that are due now: bigger batches,
        # fewer model calls (a call of 1 frame costs 2-3x a frame of 8), for at most this
        # much more latency. Only lanes whose next frame is due wait: one pair never does.
        self.gather_s = gather_ms / 1e3 if batch else 0.0
        self.owned = owned
        self.cond = threading.Condition()
        self._lanes: list[InferenceLane] = []
        self._stopping = False
        self._thread: threading.Thread | None = None
        self._turn = 0  # rotates the lane order, so no device is always run last
        self.turns = 0  # model turns run (read from any thread; an int)
        self.frames = 0  # frames run in them
        self.calls = 0  # model calls (a turn of more than max_batch frames makes several)
        self.gathered = 0  # turns that waited for due frames (gather_ms)

    def lane(
        self,
        window: Window,
        on_result: Callable[[InferenceResult], None],
        *,
        max_queue: int = 16,
    ) -> InferenceLane:
        return InferenceLane(self, window, on_result, max_queue)

    def start(self) -> None:
        with self.cond:
            if self._thread is not None:
                return
            self._stopping = False
            self._thread = threading.Thread(target=self._run, name="scotti-inference", daemon=True)
            self._thread.start()

    def attach(self, lane: InferenceLane) -> None:
        with self.cond:
            if lane not in self._lanes:
                self._lanes.append(lane)
        if self.owned:
            self.start()

    async def detach(self, lane: InferenceLane) -> None:
        with self.cond:
            if lane in self._lanes:
                self._lanes.remove(lane)
            lane.discard_waiting()
            last = not self._lanes
        if self.owned and last:
            await self.stop()

    async def stop(self) -> None:
        """Stop after the turn being run (if any)."""
        with self.cond:
            self._stopping = True
            self.cond.notify()
            thread, self._thread = self._thread, None
        if thread is not None:
            await asyncio.to_thread(thread.join, 5.0)

    # --- the worker thread ------------------------------------------------------

    def _run(self) -> None:
        while True:
            with self.cond:
                taken = self._take_ready()
                while not taken and not self._stopping:
                    self.cond.wait()
                    taken = self._take_ready()
                if self.gather_s and len(taken) < self.max_batch and not self._stopping:
                    taken += self._gather(taken)
                if self._stopping:
                    return
            for lane, _job, restart in taken:
                if restart:
                    lane.window.restart()
            for first in range(0, len(taken), self.max_batch):
                self._run_batch(taken[first : first + self.max_batch])
            self.turns += 1
            self.frames += len(taken)

    def _gather(
        self, taken: list[tuple[InferenceLane, InferenceJob, bool]]
    ) -> list[tuple[InferenceLane, InferenceJob, bool]]:
        """Wait (the condition's wait: the loop goes on submitting) until the lanes not in
        ``taken`` whose frame waits or is due within ``gather_s`` have one, or
        ``gather_s`` has passed, or the batch is full; their frames. The caller holds the
        condition."""
        now = time.monotonic()
        have = len(taken)
        in_turn = {id(lane) for lane, _, _ in taken}
        due = [
            lane
            for lane in self._lanes
            if id(lane) not in in_turn and (lane.has_waiting or lane.due_within(now, self.gather_s))
        ]
        if not due:
            return []
        self.gathered += 1
        deadline = now + self.gather_s
        while not self._stopping:
            ready = sum(1 for lane in due if lane.has_waiting)
            left = deadline - time.monotonic()
            if ready == len(due) or have + ready >= self.max_batch or left <= 0:
                break
            self.cond.wait(left)
        out = []
        for lane in due:
            item = lane.take()
            if item is not None:
                out.append((lane, *item))
        return out

    def stats(self) -> dict[str, float]:
        """What the engine did since it started, shared by every device of the daemon."""
        return {
            "model_calls": self.calls,
            "frames": self.frames,
            "frames_per_call": round(self.frames / self.calls, 2) if self.calls else 0.0,
            "gathered_turns": self.gathered,
        }

    def _take_ready(self) -> list[tuple[InferenceLane, InferenceJob, bool]]:
        """The oldest job of every lane that has one, starting one lane further each turn."""
        n = len(self._lanes)
        if not n:
            return []
        self._turn = (self._turn + 1) % n
        taken = []
        for lane in self._lanes[self._turn :] + self._lanes[: self._turn]:
            item = lane.take()
            if item is not None:
                taken.append((lane, *item))
        return taken

    def _run_batch(self, taken: list[tuple[InferenceLane, InferenceJob, bool]]) -> None:
        self.calls += 1
        start = time.perf_counter()
        try:
            outputs: list[WindowOutput | None] = list(
                Window.push_batch(
                    [lane.window for lane, _, _ in taken], [j.frame.counts for _, j, _ in taken]
                )
            )
            errors: list[str | None] = [None] * len(taken)
        except Exception as exc:  # a model failure must not kill the worker
            if len(taken) > 1:  # find whose frame it was: each device on its own
                for one in taken:
                    self._run_batch([one])
                return
            log.debug("inference failed on frame %d", taken[0][1].seq, exc_info=True)
            outputs, errors = [None], [f"{type(exc).__name__}: {exc}"]
        ms = (time.perf_counter() - start) * 1e3
        # One wake-up of each loop per turn, not one per device: the devices of a daemon
        # share its loop, and each call_soon_threadsafe writes to the loop's self-pipe.
        by_loop: dict[asyncio.AbstractEventLoop, list[tuple[InferenceLane, InferenceResult]]] = {}
        for (lane, job, restart), output, error in zip(taken, outputs, errors, strict=True):
            if lane.loop is not None:
                result = InferenceResult(job, output, ms, restart, error, len(taken))
                by_loop.setdefault(lane.loop, []).append((lane, result))
        for loop, results in by_loop.items():
            with contextlib.suppress(RuntimeError):  # a closed loop: nobody listens any more
                loop.call_soon_threadsafe(_deliver_all, results)


def _deliver_all(results: list[tuple[InferenceLane, InferenceResult]]) -> None:
    """On a loop: each result to its lane, in the order the engine ran them."""
    for lane, result in results:
        try:
            lane.deliver(result)
        except Exception:  # one device's consumer failing must not cost the others theirs
            log.exception("delivering an inference result failed")


class InferenceWorker(InferenceLane):
    """A lane on an engine of its own: one window, one thread (a single pipeline)."""

    def __init__(
        self,
        window: Window,
        on_result: Callable[[InferenceResult], None],
        *,
        max_queue: int = 16,
    ) -> None:
        super().__init__(InferenceEngine(owned=True), window, on_result, max_queue)
