"""Where training runs: the device (``--device auto|cpu|cuda``), the precision
(``--precision fp32|bf16``) and moving a batch there.

bf16 runs under ``torch.autocast`` on CPU and on CUDA alike: matrix products
and convolutions in bfloat16, reductions and the loss in float32. bf16 has
float32's exponent range, so no loss scaling is needed (unlike fp16).

Batches are built on the CPU (numpy shifts, then ``torch.from_numpy``); for
CUDA they are put in pinned (page-locked) memory by the thread that builds
them, so the copy to the GPU can be ``non_blocking`` and overlap the step
before it. On the CPU pinning would only cost, so it is done for CUDA alone.
"""

from __future__ import annotations

import contextlib
from collections.abc import Sequence

import torch
from scotti.export.errors import ExportError
from scotti.export.losses import ScottiTargets

DEVICES = ("auto", "cpu", "cuda")
PRECISIONS = ("fp32", "bf16")


class DeviceError(ExportError):
    """A device or precision this machine cannot give (one-line message)."""


def resolve_device(name: str, local_rank: int = 0) -> torch.device:
    """``auto`` -> cuda if torch sees a GPU, else cpu; cuda -> this process's GPU."""
    if name not in DEVICES:
        msg = f"--device must be one of {', '.join(DEVICES)}, got {name!r}"
        raise DeviceError(msg)
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    if name == "cpu":
        return torch.device("cpu")
    if not torch.cuda.is_available():
        msg = "--device cuda: torch sees no CUDA device (a CPU-only torch build, or no GPU)"
        raise DeviceError(msg)
    count = torch.cuda.device_count()
    if local_rank >= count:
        msg = f"local rank {local_rank} wants GPU {local_rank}, this machine has {count}"
        raise DeviceError(msg)
    torch.cuda.set_device(local_rank)
    return torch.device("cuda", local_rank)


def check_precision(precision: str, device: torch.device) -> None:
    if precision not in PRECISIONS:
        msg = f"--precision must be one of {', '.join(PRECISIONS)}, got {precision!r}"
        raise DeviceError(msg)
    if precision == "bf16" and device.type == "cuda" and not torch.cuda.is_bf16_supported():
        msg = f"--precision bf16: {torch.cuda.get_device_name(device)} has no bfloat16"
        raise DeviceError(msg)


def autocast(device: torch.device, precision: str) -> contextlib.AbstractContextManager[None]:
    """The forward pass's context: bf16 autocast, or nothing at all for fp32."""
    if precision == "fp32":
        return contextlib.nullcontext()
    return torch.autocast(device_type=device.type, dtype=torch.bfloat16)


def pin_for(device: torch.device, tensor: torch.Tensor) -> torch.Tensor:
    """Page-locked memory for a later non-blocking copy to a GPU; unchanged for the CPU."""
    return tensor.pin_memory() if device.type == "cuda" else tensor


def pin_batch(
    frames: Sequence[torch.Tensor], targets: ScottiTargets, device: torch.device
) -> tuple[list[torch.Tensor], ScottiTargets]:
    """``pin_for`` on every tensor of a batch (run in the thread that builds it)."""
    if device.type != "cuda":
        return list(frames), targets
    return [pin_for(device, f) for f in frames], ScottiTargets(
        pin_for(device, targets.pose),
        pin_for(device, targets.action),
        pin_for(device, targets.progress),
    )


def batch_to_device(
    frames: Sequence[torch.Tensor], targets: ScottiTargets, device: torch.device
) -> tuple[list[torch.Tensor], ScottiTargets]:
    """A batch on ``device``; from pinned memory the copies do not wait for the GPU."""
    if device.type == "cpu":
        return list(frames), targets
    return [f.to(device, non_blocking=True) for f in frames], ScottiTargets(
        targets.pose.to(device, non_blocking=True),
        targets.action.to(device, non_blocking=True),
        targets.progress.to(device, non_blocking=True),
    )
