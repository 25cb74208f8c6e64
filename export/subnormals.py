"""Subnormal floats (below 1.2e-38 in float32), which x86 CPUs multiply through a
microcode assist many times slower than normal numbers.

Weight decay shrinks the weights no gradient reaches geometrically (the CNN's
projection from taxels outside the insole outline, whose input is always zero)
until they are subnormal. Training then slows down epoch by epoch, and an
exported graph that carries them slows every call of a runtime that keeps IEEE
subnormals. As zeros they change no output at float32 precision.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import torch


@contextlib.contextmanager
def flushing_denormals() -> Iterator[bool]:
    """Inside: subnormal floats read and written as zero on the CPU, in this thread and
    every thread started inside (threads inherit the mode); yields whether it took.

    Enter it before torch starts its thread pool (the first parallel op). Measured on
    p1's four-layer run before this: training fell from 92 to 32 windows/s over its
    first three epochs, nearly all of it in the convolutions, with 47,795 of its
    1.2 M weights subnormal. On leaving, IEEE subnormals again (torch's default; it
    has no getter for the mode before): a process that trains in-process (the tests)
    keeps its own float arithmetic afterwards.
    """
    took = bool(torch.set_flush_denormal(True))
    try:
        yield took
    finally:
        torch.set_flush_denormal(False)


def zero_subnormal_weights(model: torch.nn.Module) -> int:
    """Set every subnormal weight and buffer of ``model`` to 0; how many there were.

    An exported graph carries its weights as they are, and an ONNX runtime that
    keeps IEEE subnormals pays for them on every call (a graph with 26,351
    subnormal weights: its window graph took 26 ms against 2.0 ms zeroed, its step
    2.3x; ``python experiments/subnormal_cost.py``).
    """
    tiny = torch.finfo(torch.float32).tiny
    zeroed = 0
    with torch.no_grad():
        for tensor in [*model.parameters(), *model.buffers()]:
            if not tensor.is_floating_point():
                continue
            sub = (tensor != 0) & (tensor.abs() < tiny)
            zeroed += int(sub.sum())
            tensor.masked_fill_(sub, 0.0)
    return zeroed
