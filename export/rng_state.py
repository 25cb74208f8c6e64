"""The random generators a training step draws dropout from, saved and put back.

One place for both users: a checkpoint keeps them so that ``--resume`` draws on
as an uninterrupted run would, and ``--keep-near-pass matched`` rewinds them so
that the reference replays the training pass's dropout masks (export/anchor.py).
"""

from __future__ import annotations

import torch

RngState = dict[str, torch.Tensor]


def rng_state(device: torch.device) -> RngState:
    """The CPU's generator, and the GPU's on a GPU (dropout there draws from it)."""
    state = {"torch": torch.get_rng_state()}
    if device.type == "cuda":
        state["cuda"] = torch.cuda.get_rng_state(device)
    return state


def set_rng_state(state: RngState, device: torch.device) -> None:
    """Put back what ``rng_state`` read (a GPU's only on a GPU, and only if saved)."""
    torch.set_rng_state(state["torch"])
    if device.type == "cuda" and "cuda" in state:
        torch.cuda.set_rng_state(state["cuda"], device)
