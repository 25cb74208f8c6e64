"""The model's streaming step alone, at several batch sizes: what batching buys.

    python -m scotti.daemon.tools.bench --step-batches 1 2 4 8 16 32 64

(the bench's option; no daemon, no broker). A measurement, never a test.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import numpy.typing as npt
from scotti.models.contract import MAX_COUNT
from scotti.models.runtime import ScottiRuntime


def step_inputs(
    runtime: ScottiRuntime, sizes: list[int]
) -> dict[int, tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]]:
    """Per batch size, frames and cached embeddings to time the step on (seeded)."""
    rng = np.random.default_rng(0)
    return {
        b: (
            rng.integers(0, MAX_COUNT // 3, (b, *runtime.frame_shape)).astype(np.float32),
            rng.normal(size=(b, runtime.window - 1, runtime.embed_dim)).astype(np.float32),
        )
        for b in sizes
    }


def step_costs(model: Path, sizes: list[int], repeats: int = 15) -> int:
    """The model's step alone: ms per frame at each batch size, sizes interleaved so
    that a busy host weighs on all of them alike."""
    runtime = ScottiRuntime(model)
    inputs = step_inputs(runtime, sizes)
    for frames, past in inputs.values():  # onnxruntime plans each new shape once
        runtime.step_batch(frames, past)
    per_frame: dict[int, list[float]] = {b: [] for b in sizes}
    for _ in range(repeats):
        for b, (frames, past) in inputs.items():
            start = time.perf_counter()
            runtime.step_batch(frames, past)
            per_frame[b].append((time.perf_counter() - start) * 1e3 / b)
    print(
        f"model step {model.name}, 1 thread, {repeats} rounds, "
        f"load average {os.getloadavg()[0]:.1f}"
    )
    print("| frames per call | ms per frame, min | median |")
    print("|---|---|---|")
    for b, values in per_frame.items():
        print(f"| {b} | {min(values):.2f} | {float(np.median(values)):.2f} |")
    return 0
