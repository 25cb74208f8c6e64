"""The model's floor beside the daemon: its step's own CPU per frame, per batch size.

The model is the one the daemon runs (``--model``), of either form
(``open_step_model``): the paper form's step on frames and cached embeddings, the
streaming-native form's on frames and warm key/value caches (``step_costs``).

The daemon cannot cost less than the model it runs: at ``b`` frames a call the
step takes ``ms(b)`` of CPU per frame, so a pair at 16 Hz needs at least
``16 * ms(b) / 1000`` of a core. The bench measures ``ms(b)`` in its own process
(one onnxruntime thread, as the daemon runs it) in CPU seconds, not wall time,
so that other work on a shared host changes it little, and prints the daemon's
CPU per pair over it: the issue's goal is at most 1.5.

The batch size is the best the engine can form: every pair's frame of a period
in one call, at most ``max_batch`` (``min(pairs, max_batch)``; 1 with one call
per pair). Smaller batches than that cost more per frame, and that cost is the
daemon's (its batching), not the model's floor.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from scotti.models.contract import FRAME_RATE_HZ


def engine_batch(pairs: int, batch: bool, max_batch: int) -> int:
    """The most frames one model call of the engine takes at ``pairs`` pairs."""
    return min(pairs, max_batch) if batch else 1


def model_cpu_ms(model: Path, sizes: list[int], seconds: float = 1.5) -> dict[int, float]:
    """CPU ms per frame of the model's step at each batch size: the median of rounds
    (sizes interleaved, so that a busy host weighs on all of them alike), about
    ``seconds`` of CPU in all."""
    from scotti.daemon.tools.step_costs import run_step, step_inputs
    from scotti.models.kv_streaming import open_step_model

    runtime = open_step_model(model)  # either form, as the daemon opens it
    sizes = sorted(set(sizes))
    inputs = step_inputs(runtime, sizes)
    for frames, *rest in inputs.values():  # onnxruntime plans each new shape once
        run_step(runtime, frames, tuple(rest))
    per_frame: dict[int, list[float]] = {b: [] for b in sizes}
    started = time.process_time()
    rounds = 0
    while rounds < 5 or (time.process_time() - started < seconds and rounds < 200):
        for b, (frames, *rest) in inputs.items():
            calls = max(1, 32 // b)  # a few calls per size: the clock's tick is coarse
            arrays = tuple(rest)
            t0 = time.process_time()
            for _ in range(calls):
                run_step(runtime, frames, arrays)
            per_frame[b].append((time.process_time() - t0) * 1e3 / (b * calls))
        rounds += 1
    return {b: float(np.median(v)) for b, v in per_frame.items()}


def core_share_per_pair(ms_per_frame: float) -> float:
    """% of one core a pair at 16 Hz needs at ``ms_per_frame`` CPU per frame."""
    return ms_per_frame * FRAME_RATE_HZ / 10.0
