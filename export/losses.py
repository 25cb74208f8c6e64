"""The SCOTTI training objective: pose (MPJPE + MPJAE), action (CE), progress (MSE).

Paper weights: total = 0.01 * pose + 1 * action + 1 * progress. The pose term
is in the units the paper reports (millimetres and degrees), which is what
makes 0.01 a sensible balance against a cross-entropy of about ln(9) ~ 2.

What each term is over: the pose term over every frame with a pose label;
the action term over frames with an action, standing included (transitions,
``NO_ACTION``, are left out); the progress term only where the progress
label is finite, so standing, transitions and missing labels are left out
whatever the action target says.

Every term is finite with finite gradients on any input: zero-length bones,
coincident points, a batch with no labelled action, NaN progress labels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from scotti.export.model import ScottiOutputs
from scotti.models import contract

_BONES = torch.as_tensor(contract.BONE_INDEX)  # (n_bones, 2) parent, child
_ANGLE_PAIRS = torch.as_tensor(contract.JOINT_ANGLES, dtype=torch.int64)  # (n_angles, 2)
_REPEATED = torch.tensor(sorted(contract.REPEATED_ACTIONS), dtype=torch.int64)  # have progress

# Floor for |a x b| in atan2 (m^2, about two 1 cm bones): keeps atan2 and its
# gradient defined when a bone has zero length, at a bias below 0.001 rad.
ANGLE_EPS = 1e-4
# Floor inside the Euclidean distance (m^2): sqrt has no gradient at 0.
DIST_EPS = 1e-12


@dataclass(frozen=True)
class LossWeights:
    pose: float = 0.01
    action: float = 1.0
    progress: float = 1.0


@dataclass(frozen=True)
class ScottiTargets:
    """Labels for the predicted time t of each window in a batch."""

    pose: torch.Tensor  # (B, 19, 3) metres; a keypoint with a NaN is left out
    action: torch.Tensor  # (B,) int64 index into ACTIONS, NO_ACTION (-1) = transition
    progress: torch.Tensor  # (B,) float in [0, 1], NaN where undefined (standing, transition)


def safe_norm(v: torch.Tensor, eps: float = DIST_EPS) -> torch.Tensor:
    """|v| over the last axis, with a finite gradient at v = 0."""
    return torch.sqrt((v * v).sum(dim=-1) + eps)


def joint_angles(pose: torch.Tensor) -> torch.Tensor:
    """(..., 19, 3) keypoints -> (..., n_angles) radians in [0, pi] per JOINT_ANGLES.

    atan2(|a x b|, a . b) is accurate at 0 and pi, where acos of a clamped
    cosine has an infinite gradient.
    """
    bones = pose[..., _BONES[:, 1], :] - pose[..., _BONES[:, 0], :]  # (..., n_bones, 3)
    a = bones[..., _ANGLE_PAIRS[:, 0], :]  # (..., n_angles, 3)
    b = bones[..., _ANGLE_PAIRS[:, 1], :]
    sin_part = safe_norm(torch.linalg.cross(a, b), eps=ANGLE_EPS**2)  # >= ANGLE_EPS
    cos_part = (a * b).sum(dim=-1)
    return torch.atan2(sin_part, cos_part)


def mpjpe_mm(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean per-joint position error, (B, 19, 3) metres -> (B,) millimetres."""
    return 1000.0 * safe_norm(pred - target).mean(dim=-1)


def mpjae_deg(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean per-joint angle error, (B, 19, 3) metres -> (B,) degrees."""
    diff = (joint_angles(pred) - joint_angles(target)).abs()
    return math.degrees(1.0) * diff.mean(dim=-1)


def angle_mask(keypoint_ok: torch.Tensor) -> torch.Tensor:
    """(..., 19) keypoints present -> (..., n_angles): both bones of the angle present."""
    bone_ok = keypoint_ok[..., _BONES[:, 0]] & keypoint_ok[..., _BONES[:, 1]]  # (..., n_bones)
    return bone_ok[..., _ANGLE_PAIRS[:, 0]] & bone_ok[..., _ANGLE_PAIRS[:, 1]]


def _row_means(values: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """(B, K) -> (B,): mean over the masked-in entries of each row (0 for an empty row)."""
    m = mask.to(values.dtype)
    return (values * m).sum(dim=-1) / m.sum(dim=-1).clamp_min(1.0)


def _masked_mean(values: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean of values where mask holds; 0 (not NaN) when nothing is masked in."""
    m = mask.to(values.dtype)
    return (values * m).sum() / m.sum().clamp_min(1.0)


def scotti_loss(
    outputs: ScottiOutputs,
    targets: ScottiTargets,
    weights: LossWeights = LossWeights(),
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """Weighted total and its detached parts (pose, mpjpe_mm, mpjae_deg, action, progress)."""
    # Unlabelled values are replaced before any arithmetic: NaN * 0 is still NaN.
    # A keypoint is left out on its own (imported data may lack some): MPJPE
    # over the keypoints present, MPJAE over the angles whose bones are present.
    keypoint_ok = torch.isfinite(targets.pose).all(dim=-1)  # (B, 19)
    pose_target = torch.where(keypoint_ok[..., None], targets.pose, outputs.pose.detach())
    distance_mm = 1000.0 * safe_norm(outputs.pose - pose_target)  # (B, 19)
    mpjpe = _masked_mean(
        _row_means(distance_mm, keypoint_ok), keypoint_ok.any(dim=-1)
    )  # mean per window, then over windows with any keypoint
    angle_ok = angle_mask(keypoint_ok)  # (B, n_angles)
    angle_error = math.degrees(1.0) * (joint_angles(outputs.pose) - joint_angles(pose_target)).abs()
    mpjae = _masked_mean(_row_means(angle_error, angle_ok), angle_ok.any(dim=-1))
    pose = mpjpe + mpjae

    labelled = targets.action != contract.NO_ACTION  # (B,) standing counts
    ce = F.cross_entropy(outputs.action_logits, targets.action.clamp_min(0), reduction="none")
    action = _masked_mean(ce, labelled)

    # Progress counts only for a repeated action with a finite label: the label is
    # NaN where progress is undefined (standing, transitions, unlabelled), and a
    # stray number on a standing frame is not trusted either.
    repeated = torch.isin(targets.action, _REPEATED.to(targets.action.device))  # (B,)
    has_progress = repeated & torch.isfinite(targets.progress)  # (B,)
    progress_target = torch.where(has_progress, targets.progress, 0.0)
    progress = _masked_mean((outputs.progress - progress_target) ** 2, has_progress)

    total = weights.pose * pose + weights.action * action + weights.progress * progress
    parts = {
        "total": total,
        "pose": pose,
        "mpjpe_mm": mpjpe,
        "mpjae_deg": mpjae,
        "action": action,
        "progress": progress,
    }
    return total, {k: v.detach() for k, v in parts.items()}
