"""An epoch's plan (which windows, in which batches, with which shifts) and its tensors.

Everything random in an epoch (window phase, chunk cuts, order, shifts,
added crosstalk, foreign sensors, tempi) is drawn from a generator seeded with (seed, epoch), so the
plan is a pure function of (dataset, options, seed, epoch): a resumed run, a
prefetch thread and every rank of a distributed run all see the same plan.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import torch
from scotti.export.augment import add_crosstalk, draw_crosstalk, draw_shifts, shift_feet
from scotti.export.evaluate import to_targets
from scotti.export.losses import ScottiTargets
from scotti.export.sensor_transfer import ForeignSensor, draw_transfer, render
from scotti.export.tempo import draw_tempo
from scotti.export.windows import Chunk, WindowDataset

if TYPE_CHECKING:
    from scotti.export.train_options import TrainOptions


@dataclass(frozen=True)
class PlannedChunk:
    chunk: Chunk
    shifts: np.ndarray  # (2, 2) (rows, cols) per foot
    crosstalk: np.ndarray = field(default_factory=lambda: np.zeros(2, dtype=np.float32))
    sensor: ForeignSensor | None = None  # read through this insole as an import (None: ours)
    tempo: float = 1.0  # played at this tempo (export/tempo.py; 1: as recorded)


def plan_epoch(dataset: WindowDataset, opts: TrainOptions, epoch: int) -> list[list[PlannedChunk]]:
    """The epoch's batches, a pure function of (dataset, options, seed, epoch)."""
    rng = np.random.default_rng([opts.seed, epoch])
    phase = int(rng.integers(opts.stride))
    chunks = dataset.chunks(stride=opts.stride, chunk=opts.chunk, phase=phase, rng=rng)
    batches: list[list[PlannedChunk]] = []
    current: list[PlannedChunk] = []
    windows = 0
    for i in rng.permutation(len(chunks)):
        shifts = draw_shifts(rng, opts.max_shift)
        # Neither draws from rng when it is off: plans without them stay as they were.
        crosstalk = draw_crosstalk(rng, opts.max_crosstalk)
        sensor = draw_transfer(rng, opts.sensor_transfer)
        tempo = draw_tempo(
            rng, opts.tempo_stretch, *opts.tempo_range, opts.tempo_extra, opts.tempo_extra_range
        )
        if not dataset.fits_tempo(chunks[i], tempo):
            tempo = 1.0
        current.append(PlannedChunk(chunks[i], shifts, crosstalk, sensor, tempo))
        windows += chunks[i].count
        if windows >= opts.batch:
            batches.append(current)
            current, windows = [], 0
    if current:
        batches.append(current)
    return batches


def batch_tensors(
    dataset: WindowDataset, batch: Sequence[PlannedChunk]
) -> tuple[list[torch.Tensor], ScottiTargets]:
    """Augmented frames (float32 counts) per chunk and the batch's targets."""
    cols = dataset.sessions[0].frames.shape[2] // 2
    frames = [
        torch.from_numpy(_augmented(dataset.frames(p.chunk, p.tempo), p, cols)) for p in batch
    ]
    return frames, to_targets([dataset.targets(p.chunk, p.tempo) for p in batch])


def _augmented(frames: np.ndarray, planned: PlannedChunk, cols: int) -> np.ndarray:
    shifted = shift_feet(frames, planned.shifts, cols).astype(np.float32)
    if planned.sensor is not None:
        shifted = render(shifted, planned.sensor)  # another insole, as an import brings it in
    if not planned.crosstalk.any():
        return shifted
    return add_crosstalk(shifted, planned.crosstalk, cols)


def warmup_cosine(total_steps: int, warmup_fraction: float) -> Callable[[int], float]:
    """LR factor: linear from ~0 to 1 over the warmup, then cosine down to 0 at the end."""
    warmup = max(1, round(warmup_fraction * total_steps))

    def factor(step: int) -> float:
        if step < warmup:
            return (step + 1) / warmup
        done = min(1.0, (step - warmup) / max(1, total_steps - warmup))
        return 0.5 * (1.0 + math.cos(math.pi * done))

    return factor
