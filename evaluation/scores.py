"""Scores the paper's way over a ``FrameScores``: the four tasks overall and per action,
the confusion matrix, the precision-margin curve and a random baseline."""

from __future__ import annotations

from typing import Any, Final

import numpy as np
from scotti.evaluation.frames import FrameScores
from scotti.models import metrics
from scotti.models.contract import ACTIONS, NO_ACTION, NUM_ACTIONS

RANDOM_SEED: Final = 0  # the random baseline's draws, fixed so that reruns agree
TRANSITION: Final = "transition"  # per-action row of frames labelled NO_ACTION


def task_metrics(frames: FrameScores) -> dict[str, float | int]:
    """The four tasks' figures (MPJPE and MPJAE for pose) over one set of frames."""
    # A frame without any labelled keypoint has NaN pose errors and is left out.
    return {
        "mpjpe_mm": metrics.mean_where(frames.position_error_m, None) * 1000.0,
        "mpjae_deg": metrics.mean_where(frames.angle_error_deg, None),
        "action_accuracy": metrics.action_accuracy(frames.action_pred, frames.action_true),
        "progress_mse": metrics.progress_mse(frames.progress_pred, frames.progress_true),
        "app": metrics.app(frames.progress_pred, frames.progress_true),
        "frames": len(frames),
        "frames_action": int(metrics.action_mask(frames.action_true).sum()),
        "frames_progress": int(metrics.progress_mask(frames.progress_true).sum()),
    }


def random_baseline(frames: FrameScores, seed: int = RANDOM_SEED) -> dict[str, float]:
    """Uniform random progress (and action) on the same frames: the paper's chance row."""
    rng = np.random.default_rng(seed)
    progress = rng.uniform(0.0, 1.0, len(frames))
    action = rng.integers(0, NUM_ACTIONS, len(frames)).astype(np.int64)
    return {
        "action_accuracy": metrics.action_accuracy(action, frames.action_true),
        "progress_mse": metrics.progress_mse(progress, frames.progress_true),
        "app": metrics.app(progress, frames.progress_true),
    }


def score(frames: FrameScores) -> dict[str, Any]:
    """Overall and per-action figures, confusion matrix, precision-margin curve.

    Standing is scored like any action (accuracy, its row of the confusion
    matrix); its progress figures are NaN (no frame has a progress label).
    Frames labelled as a transition get their own row, ``transition``.
    """
    curve = metrics.precision_margin(frames.progress_pred, frames.progress_true)
    per_action = {
        name: task_metrics(frames.subset(frames.action_true == a)) for a, name in enumerate(ACTIONS)
    }
    per_action[TRANSITION] = task_metrics(frames.subset(frames.action_true == NO_ACTION))
    return {
        "metrics": task_metrics(frames),
        "per_action": per_action,
        "confusion": {
            "actions": list(ACTIONS),
            "rows": "true action",
            "columns": "predicted action",
            "matrix": metrics.confusion_matrix(frames.action_pred, frames.action_true).tolist(),
        },
        "precision_margin": {
            "app": curve.app,
            "margins": curve.margins.tolist(),
            "precision": curve.precision.tolist(),
        },
        "random_baseline": random_baseline(frames),
    }
