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
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Final

import numpy as np
import numpy.typing as npt
from scotti.evaluation.sampling import Prediction
from scotti.firmware_protocol.pairing import PairedFrame
from scotti.models.input_checks import OUT_OF_RANGE, UNLOADED, FrameStats, frame_stats, window_flags
from scotti.models.ood import UNFAMILIAR
from scotti.models.runtime import ScottiRuntime

if TYPE_CHECKING:  # replay imports this module
    from scotti.evaluation.replay import SessionReplay

U16 = npt.NDArray[np.uint16]
# Segments run side by side in one step-graph call. scotti-default costs the same per
# row from 16 rows up (``python -m scotti.daemon.tools.bench --step-batches 1 8 16 64``:
# 0.58 to 0.60 ms per frame, 1.06 at batch 1; docs/performance.md); more rows only
# need a longer chunk for the same warm-up share.
BATCH: Final = 16
# Paired frames held at most (raw counts: 2.8 kB each, 46 MB): a longer session is
# replayed chunk after chunk, the last T-1 frames of one warming the next. 16 segments
# of 1,024 frames: 3.8 % warm-up steps.
CHUNK_FRAMES: Final = 16_384
# Shortest segment: each costs T-1 = 39 warm-up steps more, 10 % of 400.
MIN_SEGMENT_FRAMES: Final = 400
# Rows of the input checks computed together (float64 temporaries of ~6 MB).
_STATS_BLOCK: Final = 512
# The input flags of a window by (unloaded, out_of_range), in ``verdict``'s order.
_INPUT_FLAGS: Final = {
    (False, False): (),
    (True, False): (UNLOADED,),
    (False, True): (OUT_OF_RANGE,),
    (True, True): (UNLOADED, OUT_OF_RANGE),
}


@dataclass
class SegmentTrack:
    """One model's batched replay over the shared pairs: ``take`` each pair, then
    ``finish``; every prediction is in ``made`` (time order), the counts in ``out``."""

    runtime: ScottiRuntime  # the step graph
    out: SessionReplay
    batch: int = BATCH
    chunk_frames: int | None = None  # default CHUNK_FRAMES
    min_segment: int | None = None  # default MIN_SEGMENT_FRAMES
    made: list[Prediction] = field(default_factory=list)
    restarts: int = 0  # restarts of a window that held frames (as ``Window.restarts``)
    _counts: U16 = field(init=False, repr=False)
    _run_pos: npt.NDArray[np.int64] = field(init=False, repr=False)  # frames since restart
    _ext: npt.NDArray[np.int64] = field(init=False, repr=False)  # unwrapped seq
    _has_ext: npt.NDArray[np.bool_] = field(init=False, repr=False)
    _held: int = field(default=0, init=False)  # frames in the buffer
    _carried: int = field(default=0, init=False)  # of them, already scored (warm-up only)
    _run_len: int = field(default=0, init=False)

    def __post_init__(self) -> None:
        if self.batch < 1:
            msg = f"--batch must be at least 1, got {self.batch}"
            raise ValueError(msg)
        chunk = CHUNK_FRAMES if self.chunk_frames is None else self.chunk_frames
        cap = max(chunk, 2 * self.runtime.window)
        self._counts = np.empty((cap, *self.runtime.frame_shape), dtype=np.uint16)
        self._run_pos = np.zeros(cap, dtype=np.int64)
        self._ext = np.zeros(cap, dtype=np.int64)
        self._has_ext = np.zeros(cap, dtype=bool)

    def take(self, pair: PairedFrame, ext: int | None) -> None:
        """One paired frame; ``ext`` is its unwrapped seq."""
        self.out.pairs += 1
        self.out.degraded_pairs += bool(pair.flags)
        if pair.restart:
            self.restarts += bool(self._run_len)
            self._run_len = 0
        i = self._held
        self._counts[i] = pair.counts
        self._run_pos[i] = self._run_len
        self._ext[i] = ext if ext is not None else 0
        self._has_ext[i] = ext is not None
        self._run_len += 1
        self._held += 1
        if self._held == len(self._counts):
            self._replay_held()
            keep = self.runtime.window - 1  # the next chunk's warm-up
            for a in (self._counts, self._run_pos, self._ext, self._has_ext):
                a[:keep] = a[self._held - keep : self._held]
            self._held = self._carried = keep

    def finish(self) -> None:
        """Replay what is held (the session's end)."""
        self._replay_held()
        self._held = self._carried = 0

    def _replay_held(self) -> None:
        first, end = self._carried, self._held
        if end <= first:
            return
        t = self.runtime.window
        unloaded, out_of_range = window_flags(_stats(self._counts[:end]), t)
        shortest = MIN_SEGMENT_FRAMES if self.min_segment is None else self.min_segment
        lanes = max(1, min(self.batch, (end - first) // max(shortest, 1)))
        bounds = [first + (end - first) * k // lanes for k in range(lanes + 1)]
        score_from = np.array(bounds[:-1], dtype=np.int64)
        # Warm up on the T-1 frames before the segment, or from the restart after them.
        feed_from = score_from - np.minimum(t - 1, self._run_pos[score_from])
        ends = np.array(bounds[1:], dtype=np.int64)
        per_lane: list[list[Prediction]] = [[] for _ in range(lanes)]
        cache = np.zeros((lanes, 2 * (t - 1), self.runtime.embed_dim), dtype=np.float32)
        head = 0
        for step in range(int((ends - feed_from).max())):
            frame_at = feed_from + step
            active = np.flatnonzero(frame_at < ends)
            rows = frame_at[active]
            every = len(active) == lanes
            past = cache[:, head : head + t - 1] if every else cache[active, head : head + t - 1]
            start, start_cpu = time.perf_counter(), time.thread_time()
            result = self.runtime.run_steps(self._counts[rows].astype(np.float32), past)
            self.out.step_batches.append(((time.perf_counter() - start) * 1e3, len(rows)))
            self.out.model_cpu_s += time.thread_time() - start_cpu
            # Ring written twice (as models.streaming.EmbeddingCache), one head for all lanes.
            cache[active, head] = result.embedding
            cache[active, head + t - 1] = result.embedding
            head = (head + 1) % (t - 1)
            scored = (rows >= score_from[active]) & (self._run_pos[rows] >= t - 1)
            scored &= self._has_ext[rows]
            unfamiliar = result.unfamiliar
            for i in np.flatnonzero(scored):
                j = int(rows[i])
                flags = _INPUT_FLAGS[bool(unloaded[j]), bool(out_of_range[j])]
                if unfamiliar[i]:
                    flags = (*flags, UNFAMILIAR)
                per_lane[int(active[i])].append(
                    Prediction(
                        int(self._ext[j]) + 1,
                        result.pose[i],
                        result.action_probs[i],
                        float(result.progress[i]),
                        flags,
                    )
                )
        for lane in per_lane:  # lanes are contiguous and in order: time order
            self.made.extend(lane)


def _stats(counts: U16) -> FrameStats:
    """``frame_stats`` of many frames, a block at a time (bounded temporaries)."""
    parts = [frame_stats(counts[i : i + _STATS_BLOCK]) for i in range(0, len(counts), _STATS_BLOCK)]
    return FrameStats(
        *(
            np.concatenate([getattr(p, name) for p in parts])
            for name in ("force_n", "outside_share", "rail_share", "peak_share")
        )
    )
