"""Batched streaming for the streaming-native form: its step graph and a key/value
cache per segment, K segments in each call (as ``evaluation.segments`` for the paper form).

What changes from the paper form's segments (docs/streaming-native.md):

- **Warm-up.** A frame's cache row depends on the frames up to layers x (T-1) before
  it, so a prediction reads the receptive field R = T + layers x (T-1) frames
  (``KvStepRuntime.receptive_field``), not T. A segment is fed from R-1 frames before
  its first scored frame, or from the window's last restart if that is later. Its
  cache starts empty (every slot marked invalid), and the frames fed before the R-1
  that matter only fill slots that no scored prediction reads: the predictions are
  those of a ``KvStreamingWindow`` pushed frame by frame since the restart.
- **Restarts.** The daemon's window ``reset()``s its cache at a restart; here a lane
  whose frame starts a run marks its slots invalid before that step (the paper form
  needs nothing: its embeddings depend on their frame alone).

Also here: opening the runtime a step graph's metadata asks for (``open_step_graph``)
and the window graph next to a streaming-native step graph (``--every K``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scotti.evaluation.sampling import Prediction
from scotti.evaluation.segments import ChunkedSegments, _Chunk, _Stepped, add_predictions
from scotti.models.errors import ModelContractError, ModelError
from scotti.models.kv_streaming import KvStepRuntime
from scotti.models.runtime import ScottiRuntime, window_graph_for


def kv_window_graph(step: KvStepRuntime) -> ScottiRuntime:
    """The window graph next to a streaming-native step graph (the paper form's window
    contract), checked to have the step graph's T and E (a one-line ModelError if not)."""
    path = window_graph_for(step.path)
    if not path.exists():
        msg = f"no window graph {path.name} next to {step.path.name}"
        raise ModelError(msg)
    window = ScottiRuntime(path, step.threads)
    if window.graph != "window" or (window.window, window.embed_dim) != (
        step.window,
        step.embed_dim,
    ):
        msg = f"{path.name} is not the window graph of {step.path.name}"
        raise ModelContractError(msg)
    return window


@dataclass
class KvSegmentTrack(ChunkedSegments):
    """The streaming-native step graph: a key/value cache per segment."""

    runtime: KvStepRuntime  # the step graph

    def history(self) -> int:
        """A prediction reads its receptive field: R-1 frames before the newest."""
        return self.runtime.receptive_field - 1

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
        size = t - 1
        lanes = len(score_from)
        per_lane: list[list[Prediction]] = [[] for _ in range(lanes)]
        batches: list[tuple[float, int]] = []
        model_cpu_s = 0.0
        row_shape = (self.runtime.slots, self.runtime.embed_dim)
        # Ring written twice (as models.kv_streaming.KvCache), one head for all lanes.
        cache = np.zeros((lanes, 2 * size, *row_shape), dtype=np.float32)
        valid = np.zeros((lanes, 2 * size), dtype=np.float32)
        head = 0
        for step in range(int((ends - feed_from).max())):
            frame_at = feed_from + step
            active = np.flatnonzero(frame_at < ends)
            rows = frame_at[active]
            # A restart empties the window's cache (``KvStreamingWindow.reset``).
            valid[active[buf.run_pos[rows] == 0]] = 0.0
            every = len(active) == lanes
            past = cache[:, head : head + size] if every else cache[active, head : head + size]
            slots = valid[:, head : head + size] if every else valid[active, head : head + size]
            start, start_cpu = time.perf_counter(), time.thread_time()
            result = self.runtime.run_steps(buf.counts[rows].astype(np.float32), past, slots)
            batches.append(((time.perf_counter() - start) * 1e3, len(rows)))
            model_cpu_s += time.thread_time() - start_cpu
            for at in (head, head + size):
                cache[active, at] = result.embedding
                valid[active, at] = 1.0
            head = (head + 1) % size
            scored = (rows >= score_from[active]) & (buf.run_pos[rows] >= t - 1)
            scored &= buf.has_ext[rows]
            add_predictions(per_lane, buf, rows, active, scored, flags, result)
        made = [m for lane in per_lane for m in lane]  # lanes are contiguous: time order
        return _Stepped(made, batches, model_cpu_s)
