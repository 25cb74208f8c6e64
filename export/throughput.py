"""Benchmarks of training throughput (``scotti train --benchmark STEPS``).

Each compares two ways of doing the same training steps on the same
batches, alternating batch by batch, so a machine whose load changes
meanwhile slows both alike: naive against chunked embeddings, and fp32
against bf16 autocast (chunked). The first batch warms up allocators and
kernels and is not counted.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

import torch
from scotti.export.devices import autocast, batch_to_device
from scotti.export.epochs import batch_tensors, plan_epoch
from scotti.export.evaluate import chunked_outputs
from scotti.export.losses import scotti_loss
from scotti.export.model import Scotti, ScottiOutputs
from scotti.export.windows import WindowDataset

if TYPE_CHECKING:
    from scotti.export.train_options import TrainOptions


def measure_throughput(
    model: Scotti, dataset: WindowDataset, opts: TrainOptions, steps: int = 5
) -> dict[str, float]:
    """Training windows/s (forward + backward) the naive way and chunked, same batches.

    Naive: every window's T frames go through the CNN on their own, as
    ``model(frames (B, T, H, 2W))`` does. Chunked: ``chunked_outputs``. The
    two alternate batch by batch, so a machine whose load changes meanwhile
    slows both alike.
    """
    batches = plan_epoch(dataset, opts, 0)[: steps + 1]
    window = model.cfg.window
    model.train()
    seconds = {"naive": 0.0, "chunked": 0.0}
    windows = 0
    for i, batch in enumerate(batches):
        frames, targets = batch_tensors(dataset, batch)
        for way in seconds:
            started = time.perf_counter()
            if way == "naive":
                stacked = [unfold_frames(f, window, opts.stride) for f in frames]
                outputs = model(torch.cat(stacked))  # (B, T, H, 2W) in
            else:
                outputs = chunked_outputs(model, frames, window, opts.stride)
            loss, _ = scotti_loss(outputs, targets, opts.loss_weights)
            model.zero_grad(set_to_none=True)
            loss.backward()  # type: ignore[no-untyped-call]
            if i > 0:  # the first batch warms up allocators and kernels: not counted
                seconds[way] += time.perf_counter() - started
        windows += int(targets.action.shape[0]) if i > 0 else 0
    rates = {way: windows / max(1e-9, s) for way, s in seconds.items()}
    rates["ratio"] = rates["chunked"] / max(1e-9, rates["naive"])
    return rates


def unfold_frames(frames: torch.Tensor, window: int, stride: int) -> torch.Tensor:
    """Frames (L, H, 2W) -> windows of frames (K, T, H, 2W), copied: the naive layout."""
    return frames.unfold(0, window, stride).permute(0, 3, 1, 2).contiguous()


def measure_precisions(
    model: Scotti,
    dataset: WindowDataset,
    opts: TrainOptions,
    steps: int = 5,
    device: torch.device | None = None,
) -> dict[str, float]:
    """Chunked training windows/s (forward + backward) in fp32 and under bf16 autocast."""
    device = device or torch.device("cpu")
    model.to(device).train()
    batches = plan_epoch(dataset, opts, 0)[: steps + 1]
    seconds = {"fp32": 0.0, "bf16": 0.0}
    windows = 0
    for i, batch in enumerate(batches):
        frames, targets = batch_to_device(*batch_tensors(dataset, batch), device)
        for precision in seconds:
            _sync(device)
            started = time.perf_counter()
            with autocast(device, precision):
                outputs = chunked_outputs(model, frames, model.cfg.window, opts.stride)
            loss, _ = scotti_loss(ScottiOutputs(*(o.float() for o in outputs)), targets)
            model.zero_grad(set_to_none=True)
            loss.backward()  # type: ignore[no-untyped-call]
            _sync(device)
            if i > 0:
                seconds[precision] += time.perf_counter() - started
        windows += int(targets.action.shape[0]) if i > 0 else 0
    rates = {p: windows / max(1e-9, s) for p, s in seconds.items()}
    rates["ratio"] = rates["bf16"] / max(1e-9, rates["fp32"])
    return rates


def _sync(device: torch.device) -> None:
    """Wait for queued GPU work, so that the clock measures the step and not its launch."""
    if device.type == "cuda":
        torch.cuda.synchronize(device)
