"""Early stopping on a plateau of the validation loss (``--patience``, ``--min-delta``).

The decision is a pure function of the history: an epoch improves when its
validation loss is below the best so far by at least ``min_delta``; after
``patience`` epochs in a row without an improvement the run has reached its
plateau. Being a function of the history alone, it needs no state of its
own in the checkpoint, and a resumed run decides exactly as the first would.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Plateau:
    """Where a run stands: its best epoch (1-based, 0 = none yet) and epochs since."""

    best_epoch: int
    best_loss: float
    stale_epochs: int  # epochs in a row without an improvement of at least min_delta
    reached: bool


def validation_loss(record: dict[str, Any]) -> float | None:
    val = record.get("val")
    if isinstance(val, dict) and isinstance(val.get("loss"), int | float):
        return float(val["loss"])
    return None


def plateau(history: Sequence[dict[str, Any]], patience: int, min_delta: float) -> Plateau:
    """The plateau state after the epochs of ``history`` (patience 0: never reached)."""
    best_epoch, best, stale = 0, math.inf, 0
    for record in history:
        loss = validation_loss(record)
        if loss is None:
            continue  # an epoch without validation neither improves nor counts
        if loss < best - min_delta:
            best_epoch, best, stale = int(record["epoch"]), loss, 0
        else:
            stale += 1
    return Plateau(best_epoch, best, stale, reached=patience > 0 and stale >= patience)
