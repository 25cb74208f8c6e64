"""Where a training run is, and the same as plain values in its checkpoint.

``Trainer`` keeps one ``TrainState``; ``as_values`` is what ``last.pt`` and
``best.pt`` hold of it and ``from_values`` reads it back, so a run resumed
after any step reports the same epoch figures as one never stopped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any


@dataclass
class TrainState:
    """Where a run is: completed epochs, steps into the current one, and history."""

    epoch: int = 0
    step_in_epoch: int = 0  # steps of this rank's share of the epoch's plan
    global_step: int = 0
    history: list[dict[str, Any]] = field(default_factory=list)
    best_loss: float = math.inf
    # running sums of the epoch in progress, over all ranks (kept so a mid-epoch
    # resume reports the same)
    epoch_loss_sum: float = 0.0
    epoch_windows: int = 0
    epoch_anchor_sum: float = 0.0  # the --keep-near term summed over the epoch's steps


def as_values(st: TrainState) -> dict[str, Any]:
    """The checkpoint's keys for the run's position, history and running sums."""
    return {
        "epoch": st.epoch,
        "step_in_epoch": st.step_in_epoch,
        "global_step": st.global_step,
        "history": st.history,
        "best_loss": st.best_loss,
        "running": {
            "loss_sum": st.epoch_loss_sum,
            "windows": st.epoch_windows,
            "anchor_sum": st.epoch_anchor_sum,
        },
    }


def from_values(ckpt: dict[str, Any]) -> TrainState:
    """``as_values`` read back (a checkpoint from before --keep-near has no anchor sum)."""
    return TrainState(
        epoch=int(ckpt["epoch"]),
        step_in_epoch=int(ckpt["step_in_epoch"]),
        global_step=int(ckpt["global_step"]),
        history=list(ckpt.get("history", [])),
        best_loss=float(ckpt.get("best_loss", math.inf)),
        epoch_loss_sum=float(ckpt["running"]["loss_sum"]),
        epoch_windows=int(ckpt["running"]["windows"]),
        epoch_anchor_sum=float(ckpt["running"].get("anchor_sum", 0.0)),
    )
