"""Sampled evaluation: every K-th prediction time, through the window graph in batches.

The streaming window (``scotti.daemon.inference.window.Window``) runs the step graph on every
frame. To score a uniform sample of prediction times cheaply, this keeps the
raw counts of the last T paired frames instead, with the window's rules: a
restart forgets them, the first prediction needs T frames in, and a window of
frames t-T..t-1 predicts time t. Every K-th prediction (counted from the start
of the session, so the sample ignores restarts) is queued as a copy of its T
frames and run through the window graph, ``batch_size`` windows at a time.
The export's parity tests prove that graph equals the step graph fed frame by
frame, so the sampled predictions are the streaming ones at those times.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt
from scotti.firmware_protocol.pairing import PairedFrame
from scotti.models.input_checks import check_window
from scotti.models.ood import UNFAMILIAR
from scotti.models.runtime import ScottiRuntime

if TYPE_CHECKING:  # evaluation imports this module
    from scotti.evaluation.decoded import PairBlock
    from scotti.evaluation.replay import SessionReplay

F32 = npt.NDArray[np.float32]
U16 = npt.NDArray[np.uint16]
# Windows per run of the window graph. Its activations (T frames through the CNN per
# window) stay in onnxruntime's arena at their peak: 64 windows held ~900 MB
# (scotti-default, T=40), 8 hold under 200 MB and run as fast (`/usr/bin/time -v
# scotti eval SESSION --every 8`: 961 MB at 64, 211 MB at 8).
BATCH_SIZE = 8


@dataclass(frozen=True)
class Prediction:
    """One scored prediction, for the time with unwrapped seq ``ext``."""

    ext: int
    pose: F32  # (19, 3)
    probs: F32  # (NUM_ACTIONS,)
    progress: float
    flags: tuple[str, ...] = ()  # the model's OOD flags (models/ood.py OOD_FLAGS)


@dataclass
class SampledTrack:
    """One model's sampled windows over the shared pairs: ``take`` each pair, then
    ``finish``; every K-th prediction is in ``made``, the counts in ``out``."""

    runtime: ScottiRuntime  # the window graph
    every: int
    out: SessionReplay
    batch_size: int = BATCH_SIZE
    made: list[Prediction] = field(default_factory=list)
    predictions: int = 0  # prediction times passed, scored or not
    restarts: int = 0  # restarts of a window that held frames (as ``Window.restarts``)
    _ring: U16 = field(init=False, repr=False)
    _head: int = field(default=0, init=False)
    _held: int = field(default=0, init=False)
    _queue: list[tuple[int, U16]] = field(default_factory=list, init=False, repr=False)

    def __post_init__(self) -> None:
        t = self.runtime.window
        # Written twice (slot i and i + T), so ring[head : head + T] is the window in order.
        self._ring = np.zeros((2 * t, *self.runtime.frame_shape), dtype=np.uint16)

    def take(self, pair: PairedFrame, ext: int | None) -> None:
        """One paired frame; ``ext`` is its unwrapped seq."""
        self._take(pair.counts, bool(pair.flags), pair.restart, ext)

    def take_block(self, block: PairBlock) -> None:
        """Successive paired frames (``evaluation.decoded``)."""
        for i, (degraded, restart, ext, known) in enumerate(
            zip(
                block.degraded.tolist(),
                block.restart.tolist(),
                block.ext.tolist(),
                block.has_ext.tolist(),
                strict=True,
            )
        ):
            self._take(block.counts[i], degraded, restart, ext if known else None)

    def _take(self, counts: U16, degraded: bool, restart: bool, ext: int | None) -> None:
        t = self.runtime.window
        self.out.pairs += 1
        self.out.degraded_pairs += degraded
        if restart:
            self.restarts += bool(self._held)
            self._held = 0
        self._ring[self._head] = counts
        self._ring[self._head + t] = counts
        self._head = (self._head + 1) % t
        self._held += 1
        if self._held < t or ext is None:
            return
        self.predictions += 1
        if self.predictions % self.every == 0:
            self._queue.append((ext + 1, self._ring[self._head : self._head + t].copy()))
            if len(self._queue) >= self.batch_size:
                self.finish()

    def finish(self) -> None:
        """Run the queued windows through the window graph."""
        if not self._queue:
            return
        frames = np.stack([w for _, w in self._queue])
        start, start_cpu = time.perf_counter(), time.thread_time()
        result = self.runtime.run_windows(frames, batch_size=len(frames))
        self.out.window_batches.append(((time.perf_counter() - start) * 1e3, len(frames)))
        self.out.model_cpu_s += time.thread_time() - start_cpu
        unfamiliar = result.unfamiliar
        for i, (ext, window) in enumerate(self._queue):
            flags = (*check_window(window).flags, *((UNFAMILIAR,) if unfamiliar[i] else ()))
            self.made.append(
                Prediction(
                    ext, result.pose[i], result.action_probs[i], float(result.progress[i]), flags
                )
            )
        self._queue.clear()


def window_timing(batches: list[tuple[float, int]]) -> dict[str, Any]:
    """Batched throughput per scored window: not the latency of one streaming step."""
    windows = sum(n for _, n in batches)
    return {
        "mean": sum(ms for ms, _ in batches) / windows if windows else float("nan"),
        "windows": windows,
        "batches": len(batches),
        "batch_size": BATCH_SIZE,
    }
