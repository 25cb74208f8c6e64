"""Batched streaming: how evaluation runs the model for every prediction, K segments at a time.

The daemon's window runs one step-graph call per paired frame. Here the
paired frames of a session are held (raw counts,
``CHUNK_FRAMES`` at most at a time) and cut into K contiguous segments; one
onnxruntime call per time step then runs the step of all K segments at once,
on the graph's batch axis, each segment with its own embedding cache.

Why the predictions are the sequential ones: a prediction reads the newest
frame and the cached embeddings of the T-1 frames before it, and a frame's
embedding depends on that frame alone (the per-frame CNN). So a segment that
starts at frame s is fed from frame s-(T-1) (its warm-up, not scored), or from
the window's last restart if that is later, exactly as the sequential window
was; the input checks (``unloaded``, ``out_of_range``) of the window ending at
each frame are computed for all held frames at once
(``models.input_checks.window_flags``). A restart inside a segment needs
nothing: the first T-1 frames after it are warm-up there as in the daemon.

The warm-up costs T-1 extra steps per segment, so a segment is at least
``MIN_SEGMENT_FRAMES`` long (under 10 % extra); a short session gets fewer
segments, down to one (``batch=1``: frame by frame). ``tests/test_evaluation_segments.py``
compares every prediction and flag with the daemon's own window stepped frame by
frame, on a real exported model.

With ``jobs`` J > 1 the segments are stepped on J threads (onnxruntime lets go
of the GIL during a call) while the caller takes the next chunk: a chunk of J x
``CHUNK_FRAMES`` cut into J groups of K, one chunk in flight (two held, J x 46 MB
of counts); or, when a decode worker streams the pairs in (``streamed``), each
chunk of ``STREAMED_CHUNK_FRAMES`` to one thread as soon as it is full, J in
flight. The caller computes a chunk's input checks before it waits for room.
Two jobs run 1.5x the frames per second of one on two cores (docs/evaluation.md,
"How fast it runs").
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterator
from concurrent.futures import Executor, Future
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Final, Protocol

import numpy as np
import numpy.typing as npt
from scotti.evaluation.decoded import PairBlock
from scotti.evaluation.sampling import Prediction
from scotti.firmware_protocol.pairing import PairedFrame
from scotti.models.input_checks import OUT_OF_RANGE, UNLOADED, FrameStats, frame_stats, window_flags
from scotti.models.ood import UNFAMILIAR
from scotti.models.runtime import ScottiRuntime, StepBatch

if TYPE_CHECKING:  # replay imports this module
    from scotti.evaluation.replay import SessionReplay

U16 = npt.NDArray[np.uint16]
# Segments run side by side in one step-graph call. scotti-default costs the same per
# row from 8 rows up (``python -m scotti.daemon.tools.bench --step-batches 1 8 16 64``:
# 0.41 to 0.44 ms per frame, 1.10 at batch 1; docs/performance.md); more rows only
# need a longer chunk for the same warm-up share.
BATCH: Final = 16
# Paired frames a chunk holds per job (raw counts: 2.8 kB each, 46 MB): a longer session
# is replayed chunk after chunk, the last T-1 frames of one warming the next. 16 segments
# of 1,024 frames: 3.8 % warm-up steps (11 % for the streaming-native form's R-1 = 117).
CHUNK_FRAMES: Final = 16_384
# A chunk when a decode worker streams the pairs in: stepped as soon as it is full, so
# the threads start after 8,192 pairs rather than 32,768 (``python -m
# scotti.evaluation.speed``: docs/performance.md).
STREAMED_CHUNK_FRAMES: Final = 8_192
# Shortest segment: each costs T-1 = 39 warm-up steps more, 10 % of 400.
MIN_SEGMENT_FRAMES: Final = 400
# Python's switch interval while step loops run on threads (``quick_gil_handoff``).
GIL_SWITCH_S: Final = 0.0005
# Rows of the input checks computed together (float64 temporaries of ~6 MB).
_STATS_BLOCK: Final = 512
# The input flags of a window by (unloaded, out_of_range), in ``verdict``'s order.
_INPUT_FLAGS: Final = {
    (False, False): (),
    (True, False): (UNLOADED,),
    (False, True): (OUT_OF_RANGE,),
    (True, True): (UNLOADED, OUT_OF_RANGE),
}


@dataclass(frozen=True)
class _Chunk:
    """Held paired frames handed to the step loops (not written while they run)."""

    counts: U16  # (N, H, 2W)
    run_pos: npt.NDArray[np.int64]
    ext: npt.NDArray[np.int64]
    has_ext: npt.NDArray[np.bool_]


@dataclass
class _Stepped:
    """What one group of lanes gave: its predictions in time order, its calls' timing."""

    made: list[Prediction]
    step_batches: list[tuple[float, int]]
    model_cpu_s: float


class SegmentModel(Protocol):
    """What the chunking needs of a step graph (``ScottiRuntime``, ``KvStepRuntime``)."""

    @property
    def window(self) -> int: ...

    @property
    def frame_shape(self) -> tuple[int, int]: ...


@dataclass
class ChunkedSegments:
    """One model's batched replay over the shared pairs: ``take`` each pair, then
    ``finish``; every prediction is in ``made`` (time order), the counts in ``out``.
    ``_step_lanes`` (the model's step loop) is the subclass's: ``SegmentTrack`` for the
    paper form, ``evaluation.kv_segments.KvSegmentTrack`` for the streaming-native one.

    ``jobs`` > 1 with a ``pool``: the segments are stepped on the pool's threads
    (onnxruntime lets go of the GIL while it runs) while the caller takes the next
    chunk, one of two ways:

    - the caller decodes (``streamed`` False): a chunk holds ``jobs`` x
      ``CHUNK_FRAMES`` frames, cut into ``jobs`` groups of ``batch`` lanes; one chunk
      in flight at most, so two are held;
    - a decode worker does (``streamed``, ``evaluation.decoded``): the caller only
      copies pairs, so a chunk of ``STREAMED_CHUNK_FRAMES`` goes to a thread as one
      group as soon as it is full, up to ``jobs`` chunks in flight (``jobs`` + 1
      held). The first chunk starts sooner, for more warm-up steps; with the
      caller's decoding in the way of the threads it did not pay.

    The last chunk, the session's end, is cut into ``jobs`` groups either way."""

    runtime: SegmentModel  # the step graph
    out: SessionReplay
    batch: int = BATCH
    chunk_frames: int | None = None  # default CHUNK_FRAMES
    min_segment: int | None = None  # default MIN_SEGMENT_FRAMES
    jobs: int = 1
    pool: Executor | None = None  # needed for jobs > 1
    streamed: bool = False  # pairs come decoded from a worker: step each chunk when full
    made: list[Prediction] = field(default_factory=list)
    restarts: int = 0  # restarts of a window that held frames (as ``Window.restarts``)
    _cap: int = field(default=0, init=False)  # frames a chunk holds
    _buf: _Chunk = field(init=False, repr=False)
    _in_flight: list[Future[_Stepped]] = field(default_factory=list, init=False, repr=False)
    _held: int = field(default=0, init=False)  # frames in the buffer
    _carried: int = field(default=0, init=False)  # of them, already scored (warm-up only)
    _run_len: int = field(default=0, init=False)

    def __post_init__(self) -> None:
        if self.batch < 1:
            msg = f"--batch must be at least 1, got {self.batch}"
            raise ValueError(msg)
        if self.jobs < 1:
            msg = f"--jobs must be at least 1, got {self.jobs}"
            raise ValueError(msg)
        if self.jobs > 1 and self.pool is None:
            msg = "jobs > 1 needs a pool of threads"
            raise ValueError(msg)
        default = STREAMED_CHUNK_FRAMES if self.streamed else CHUNK_FRAMES * self.jobs
        chunk = default if self.chunk_frames is None else self.chunk_frames
        self._cap = max(chunk, 2 * (self.history() + 1))
        self._buf = self._new_buffer()

    def history(self) -> int:
        """Frames before a prediction's newest one that it reads: a segment's warm-up."""
        return self.runtime.window - 1

    def _new_buffer(self) -> _Chunk:
        cap = self._cap
        return _Chunk(
            np.empty((cap, *self.runtime.frame_shape), dtype=np.uint16),
            np.zeros(cap, dtype=np.int64),
            np.zeros(cap, dtype=np.int64),
            np.zeros(cap, dtype=bool),
        )

    def take(self, pair: PairedFrame, ext: int | None) -> None:
        """One paired frame; ``ext`` is its unwrapped seq."""
        self.take_block(PairBlock.of([pair], [ext], []))

    def take_block(self, block: PairBlock) -> None:
        """Successive paired frames (``evaluation.decoded``), held a chunk at a time."""
        n = len(block)
        self.out.pairs += n
        self.out.degraded_pairs += int(np.count_nonzero(block.degraded))
        start = 0
        while start < n:
            end = min(n, start + self._cap - self._held)
            self._hold(block, start, end)
            start = end
            if self._held == self._cap:
                self._step_held()
                keep = self.history()  # the next chunk's warm-up
                # In flight, the old buffer is the step loops' until they end: a new one.
                buf = self._buf
                new = self._new_buffer() if self._in_flight else buf
                for a, b in zip(_arrays(new), _arrays(buf), strict=True):
                    a[:keep] = b[self._held - keep : self._held]
                self._buf = new
                self._held = self._carried = keep

    def _hold(self, block: PairBlock, start: int, end: int) -> None:
        """Rows ``start:end`` of the block into the buffer, each with its place in the
        window's run (a restart starts the run over, as ``Window`` does)."""
        restart = block.restart[start:end]
        at = np.arange(end - start)
        last_restart = np.maximum.accumulate(np.where(restart, at, -1))
        run_pos = np.where(last_restart >= 0, at - last_restart, self._run_len + at)
        before = np.concatenate(([self._run_len], run_pos[:-1] + 1))  # the run a restart ends
        self.restarts += int(np.count_nonzero(restart & (before > 0)))
        self._run_len = int(run_pos[-1]) + 1
        i, buf = self._held, self._buf
        rows = slice(i, i + end - start)
        buf.counts[rows] = block.counts[start:end]
        buf.run_pos[rows] = run_pos
        buf.ext[rows] = block.ext[start:end]
        buf.has_ext[rows] = block.has_ext[start:end]
        self._held += end - start

    def finish(self) -> None:
        """Replay what is held (the session's end) and wait for every step loop."""
        self._step_held(last=True)
        self._collect(0)
        self._held = self._carried = 0

    def _step_held(self, *, last: bool = False) -> None:
        """Cut the held frames into segments and step them: on the pool with jobs > 1,
        in ``jobs`` groups (``streamed`` and not ``last``: one)."""
        first, end = self._carried, self._held
        if end <= first:
            return
        t = self.runtime.window
        # The input checks of every held frame's window, here: this thread decodes faster
        # than the step loops run, and waits for them below while they step the chunks before.
        flags = window_flags(_stats(self._buf.counts[:end]), t)
        groups_of = 1 if self.streamed and not last else self.jobs
        self._collect(self.jobs - groups_of)  # room for these groups: jobs in flight at most
        shortest = MIN_SEGMENT_FRAMES if self.min_segment is None else self.min_segment
        lanes = max(1, min(self.batch * groups_of, (end - first) // max(shortest, 1)))
        bounds = [first + (end - first) * k // lanes for k in range(lanes + 1)]
        score_from = np.array(bounds[:-1], dtype=np.int64)
        # Warm up on the frames before the segment it reads, or from the restart after them.
        feed_from = score_from - np.minimum(self.history(), self._buf.run_pos[score_from])
        ends = np.array(bounds[1:], dtype=np.int64)
        for g in np.array_split(np.arange(lanes), min(groups_of, lanes)):
            args = (self._buf, flags, score_from[g], feed_from[g], ends[g])
            if self.pool is None or self.jobs == 1:
                done: Future[_Stepped] = Future()
                done.set_result(self._step_lanes(*args))
                self._in_flight.append(done)
            else:
                self._in_flight.append(self.pool.submit(self._step_lanes, *args))
        if self.pool is None or self.jobs == 1:
            self._collect(0)

    def _collect(self, keep: int) -> None:
        """The predictions of the groups in flight, oldest first (so in time order),
        until at most ``keep`` are left stepping."""
        try:
            while len(self._in_flight) > keep:
                stepped = self._in_flight[0].result()
                self._in_flight.pop(0)
                self.made.extend(stepped.made)
                self.out.step_batches.extend(stepped.step_batches)
                self.out.model_cpu_s += stepped.model_cpu_s
        except BaseException:
            self._in_flight = []  # a failed step loop: the replay is over
            raise

    def _step_lanes(
        self,
        buf: _Chunk,
        flags: tuple[npt.NDArray[np.bool_], npt.NDArray[np.bool_]],
        score_from: npt.NDArray[np.int64],
        feed_from: npt.NDArray[np.int64],
        ends: npt.NDArray[np.int64],
    ) -> _Stepped:
        """Step contiguous segments side by side (the model's own step loop)."""
        raise NotImplementedError


def add_predictions(
    per_lane: list[list[Prediction]],
    buf: _Chunk,
    rows: npt.NDArray[np.int64],
    active: npt.NDArray[np.int64],
    scored: npt.NDArray[np.bool_],
    flags: tuple[npt.NDArray[np.bool_], npt.NDArray[np.bool_]],
    result: StepBatch,
) -> None:
    """One step's scored rows as predictions, each to its lane (either form's step)."""
    unloaded, out_of_range = flags  # (unloaded, out_of_range) of the window ending at j
    unfamiliar = result.unfamiliar
    for i in np.flatnonzero(scored):
        j = int(rows[i])
        named = _INPUT_FLAGS[bool(unloaded[j]), bool(out_of_range[j])]
        if unfamiliar[i]:
            named = (*named, UNFAMILIAR)
        per_lane[int(active[i])].append(
            Prediction(
                int(buf.ext[j]) + 1,
                result.pose[i],
                result.action_probs[i],
                float(result.progress[i]),
                named,
            )
        )


@dataclass
class SegmentTrack(ChunkedSegments):
    """The paper form's step graph: an embedding cache per segment."""

    runtime: ScottiRuntime  # the step graph

    def _step_lanes(
        self,
        buf: _Chunk,
        flags: tuple[npt.NDArray[np.bool_], npt.NDArray[np.bool_]],
        score_from: npt.NDArray[np.int64],
        feed_from: npt.NDArray[np.int64],
        ends: npt.NDArray[np.int64],
    ) -> _Stepped:
        """Step contiguous segments side by side, one call of the step graph per time step.

        Runs on a pool thread with jobs > 1: it touches nothing but its arguments."""
        t = self.runtime.window
        lanes = len(score_from)
        per_lane: list[list[Prediction]] = [[] for _ in range(lanes)]
        batches: list[tuple[float, int]] = []
        model_cpu_s = 0.0
        cache = np.zeros((lanes, 2 * (t - 1), self.runtime.embed_dim), dtype=np.float32)
        head = 0
        for step in range(int((ends - feed_from).max())):
            frame_at = feed_from + step
            active = np.flatnonzero(frame_at < ends)
            rows = frame_at[active]
            every = len(active) == lanes
            past = cache[:, head : head + t - 1] if every else cache[active, head : head + t - 1]
            start, start_cpu = time.perf_counter(), time.thread_time()
            result = self.runtime.run_steps(buf.counts[rows].astype(np.float32), past)
            batches.append(((time.perf_counter() - start) * 1e3, len(rows)))
            model_cpu_s += time.thread_time() - start_cpu
            # Ring written twice (as models.streaming.EmbeddingCache), one head for all lanes.
            cache[active, head] = result.embedding
            cache[active, head + t - 1] = result.embedding
            head = (head + 1) % (t - 1)
            scored = (rows >= score_from[active]) & (buf.run_pos[rows] >= t - 1)
            scored &= buf.has_ext[rows]
            add_predictions(per_lane, buf, rows, active, scored, flags, result)
        made = [m for lane in per_lane for m in lane]  # lanes are contiguous: time order
        return _Stepped(made, batches, model_cpu_s)


@contextmanager
def quick_gil_handoff(interval_s: float = GIL_SWITCH_S) -> Iterator[None]:
    """Python's switch interval at most ``interval_s`` while the step loops run on threads.

    A loop that comes back from onnxruntime needs the GIL for its next call; at the
    default 5 ms the thread decoding the session keeps it that long, longer than half
    a 16-row call takes, so the loops would wait about as long as they compute."""
    before = sys.getswitchinterval()
    sys.setswitchinterval(min(before, interval_s))
    try:
        yield
    finally:
        sys.setswitchinterval(before)


def _arrays(buf: _Chunk) -> tuple[npt.NDArray[Any], ...]:
    return (buf.counts, buf.run_pos, buf.ext, buf.has_ext)


def _stats(counts: U16) -> FrameStats:
    """``frame_stats`` of many frames, a block at a time (bounded temporaries)."""
    parts = [frame_stats(counts[i : i + _STATS_BLOCK]) for i in range(0, len(counts), _STATS_BLOCK)]
    return FrameStats(
        *(
            np.concatenate([getattr(p, name) for p in parts])
            for name in ("force_n", "outside_share", "rail_share", "peak_share")
        )
    )
