"""The model's streaming step alone, at several batch sizes: what batching buys.

    python -m scotti.daemon.tools.bench --step-batches 1 2 4 8 16 32 64 [--model M]

(the bench's option; no daemon, no broker). The model is either form the daemon
serves (``open_step_model``): the paper form's step takes the new frames and each
one's cached embeddings, the streaming-native form's the new frames, each one's
key/value cache at a full window and its valid mask (docs/streaming-native.md).
A measurement, never a test.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import numpy.typing as npt
from scotti.models.contract import MAX_COUNT
from scotti.models.kv_streaming import KvStepRuntime, KvStreamingWindow, StepModel, open_step_model
from scotti.models.kv_streaming import push_many as kv_push_many
from scotti.models.runtime import StepBatch

F32 = npt.NDArray[np.float32]
# What one step call takes after the frames: (past embeddings,) for the paper form,
# (past keys/values, valid mask) for the streaming-native form.
StepArrays = tuple[F32, ...]


def step_inputs(runtime: StepModel, sizes: list[int]) -> dict[int, StepArrays]:
    """Per batch size, the step's inputs to time it on (seeded), frames first."""
    rng = np.random.default_rng(0)
    if isinstance(runtime, KvStepRuntime):
        past, valid = warm_kv_caches(runtime, max(sizes))
        return {b: (_frames(rng, runtime, b), past[:b].copy(), valid[:b].copy()) for b in sizes}
    # The paper form's draws, in this order, are the figures' inputs since the bench began.
    return {
        b: (
            _frames(rng, runtime, b),
            rng.normal(size=(b, runtime.window - 1, runtime.embed_dim)).astype(np.float32),
        )
        for b in sizes
    }


def _frames(rng: np.random.Generator, runtime: StepModel, b: int) -> F32:
    return rng.integers(0, MAX_COUNT // 3, (b, *runtime.frame_shape)).astype(np.float32)


def warm_kv_caches(runtime: KvStepRuntime, windows: int) -> tuple[F32, F32]:
    """``windows`` caches as ``KvStreamingWindow`` holds them once warm, (B, T-1, S, E)
    and (B, T-1): T-1 seeded frames pushed through the step graph itself, so the rows
    are the graph's own and every slot is valid."""
    rng = np.random.default_rng(1)
    made = [KvStreamingWindow(runtime) for _ in range(windows)]
    for _ in range(runtime.window - 1):
        kv_push_many(made, list(_frames(rng, runtime, windows)))
    return np.stack([w.past() for w in made]), np.stack([w.valid() for w in made])


def run_step(runtime: StepModel, frames: F32, rest: StepArrays) -> StepBatch:
    """One step call of either form on ``step_inputs``' arrays."""
    if isinstance(runtime, KvStepRuntime):
        past, valid = rest
        return runtime.run_steps(frames, past, valid)
    (past,) = rest
    return runtime.run_steps(frames, past)


def step_rows(runtime: StepModel, frames: F32, rest: StepArrays) -> int:
    """One step call and a result object per row: what ``ScottiRuntime.step_batch`` does."""
    batch = run_step(runtime, frames, rest)
    return len([batch.row(i) for i in range(len(frames))])


def form_of(runtime: StepModel) -> str:
    """The form in a few words, for the printed header."""
    if isinstance(runtime, KvStepRuntime):
        return f"streaming-native (key/value cache, T={runtime.window}, S={runtime.slots})"
    return f"paper form (embedding cache, T={runtime.window})"


def step_costs(model: Path, sizes: list[int], repeats: int = 15) -> int:
    """The model's step alone: ms per frame at each batch size, sizes interleaved so
    that a busy host weighs on all of them alike."""
    runtime = open_step_model(model)
    inputs = step_inputs(runtime, sizes)
    for frames, *rest in inputs.values():  # onnxruntime plans each new shape once
        step_rows(runtime, frames, tuple(rest))
    per_frame: dict[int, list[float]] = {b: [] for b in sizes}
    for _ in range(repeats):
        for b, (frames, *rest) in inputs.items():
            start = time.perf_counter()
            step_rows(runtime, frames, tuple(rest))
            per_frame[b].append((time.perf_counter() - start) * 1e3 / b)
    print(
        f"model step {model.name}, {form_of(runtime)}, 1 thread, {repeats} rounds, "
        f"load average {os.getloadavg()[0]:.1f}"
    )
    print("| frames per call | ms per frame, min | median |")
    print("|---|---|---|")
    for b, values in per_frame.items():
        print(f"| {b} | {min(values):.2f} | {float(np.median(values)):.2f} |")
    return 0
