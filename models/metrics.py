"""Task metrics: pose (MPJPE, MPJAE), action (accuracy, confusion), progress (MSE, APP).

Frames without a label are left out with explicit masks: actions equal to
``NO_ACTION`` (transitions) and progress that is NaN (standing, transitions:
progress is defined only for ``contract.REPEATED_ACTIONS``). Standing is an
action like the others in accuracy and the confusion matrix. A metric over no
frames is NaN (the confusion matrix is then all zeros).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scotti.models.contract import BONE_INDEX, JOINT_ANGLES, NO_ACTION, NUM_ACTIONS, NUM_KEYPOINTS
from scotti.models.errors import ModelInputError

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class PrecisionMargin:
    """APP and its curve: precision(m) = share of frames with |error| <= m."""

    app: float  # area under precision(m) for m in [0, 1]
    margins: FloatArray  # (M,) from 0 to 1
    precision: FloatArray  # (M,)
    frames: int  # labelled frames the figures are over


def mpjpe_mm(pred: npt.ArrayLike, true: npt.ArrayLike, mask: npt.ArrayLike | None = None) -> float:
    """Mean per joint position error in millimetres; keypoints (..., 19, 3) in metres."""
    distance = position_error_m(pred, true)
    return _masked_mean(distance, _with_any(mask, distance)) * 1000.0


def position_error_m(pred: npt.ArrayLike, true: npt.ArrayLike) -> FloatArray:
    """(N,) each frame's mean keypoint distance in metres; NaN where no keypoint is labelled.

    MPJPE is the mean of these over frames (``mpjpe_mm``): pooled scoring keeps
    them instead of the poses (``evaluation.frames.FrameScores``).
    """
    p, t = _pair_of_poses(pred, true)
    # A keypoint the label lacks (NaN, e.g. imported data) is left out on its own.
    return _nan_row_mean(np.linalg.norm(p - t, axis=-1))


def joint_angles_deg(keypoints: npt.ArrayLike) -> FloatArray:
    """The contract's joint angles (..., len(JOINT_ANGLES)) in degrees, 0..180.

    atan2(|u x v|, u . v) instead of arccos: exact near 0 and 180 degrees and
    finite (0) when a bone has zero length.
    """
    k = np.asarray(keypoints, dtype=np.float64)
    bones = k[..., BONE_INDEX[:, 1], :] - k[..., BONE_INDEX[:, 0], :]  # (..., B, 3)
    pairs = np.array(JOINT_ANGLES)
    u, v = bones[..., pairs[:, 0], :], bones[..., pairs[:, 1], :]  # (..., J, 3)
    sin = np.linalg.norm(np.cross(u, v), axis=-1)
    cos = np.sum(u * v, axis=-1)
    return np.asarray(np.degrees(np.arctan2(sin, cos)), dtype=np.float64)


def mpjae_deg(pred: npt.ArrayLike, true: npt.ArrayLike, mask: npt.ArrayLike | None = None) -> float:
    """Mean per joint angle error in degrees over ``contract.JOINT_ANGLES``."""
    error = angle_error_deg(pred, true)
    return _masked_mean(error, _with_any(mask, error))


def angle_error_deg(pred: npt.ArrayLike, true: npt.ArrayLike) -> FloatArray:
    """(N,) each frame's mean joint angle error in degrees; NaN where no angle is labelled."""
    p, t = _pair_of_poses(pred, true)
    return _nan_row_mean(np.abs(joint_angles_deg(p) - joint_angles_deg(t)))


def action_mask(true: npt.ArrayLike) -> npt.NDArray[np.bool_]:
    """Frames that carry an action label (not ``NO_ACTION``)."""
    return np.asarray(np.asarray(true) != NO_ACTION)


def action_accuracy(pred: npt.ArrayLike, true: npt.ArrayLike) -> float:
    """Share of labelled frames whose predicted action index is the true one."""
    p, t = _pair_of_actions(pred, true)
    keep = action_mask(t)
    return _masked_mean((p == t).astype(np.float64), keep)


def confusion_matrix(pred: npt.ArrayLike, true: npt.ArrayLike) -> npt.NDArray[np.int64]:
    """(NUM_ACTIONS, NUM_ACTIONS) counts, rows = true action, columns = predicted;
    transitions (``NO_ACTION``) left out."""
    p, t = _pair_of_actions(pred, true)
    keep = action_mask(t)
    if np.any((p[keep] < 0) | (p[keep] >= NUM_ACTIONS)):
        msg = f"predicted actions must be 0..{NUM_ACTIONS - 1}"
        raise ModelInputError(msg)
    flat = t[keep] * NUM_ACTIONS + p[keep]
    counts = np.bincount(flat, minlength=NUM_ACTIONS * NUM_ACTIONS)
    return counts.reshape(NUM_ACTIONS, NUM_ACTIONS).astype(np.int64)


def progress_mask(true: npt.ArrayLike) -> npt.NDArray[np.bool_]:
    """Frames with a progress label (finite: NaN where progress is undefined)."""
    return np.asarray(np.isfinite(np.asarray(true, dtype=np.float64)))


def progress_mse(pred: npt.ArrayLike, true: npt.ArrayLike) -> float:
    """Mean squared progress error over the labelled frames."""
    p, t = _pair_of_progress(pred, true)
    keep = progress_mask(t)
    return _masked_mean((p[keep] - t[keep]) ** 2, None)


def precision_margin(
    pred: npt.ArrayLike, true: npt.ArrayLike, num_margins: int = 101
) -> PrecisionMargin:
    """APP (Becattini et al.): the area under precision(m) for margins m in [0, 1].

    precision(m) is a step function of m, so the area is computed exactly from
    the sorted errors (not from the sampled curve): between consecutive sorted
    errors e_(k) <= m < e_(k+1), precision is k/N. Errors beyond 1 never count.
    """
    p, t = _pair_of_progress(pred, true)
    keep = progress_mask(t)
    # A non-finite prediction is a miss at every margin.
    error = np.abs(p[keep] - t[keep])
    error = np.sort(np.minimum(np.nan_to_num(error, nan=1.0, posinf=1.0), 1.0))
    margins = np.linspace(0.0, 1.0, max(num_margins, 2))
    n = error.size
    if n == 0:
        return PrecisionMargin(float("nan"), margins, np.full(margins.size, np.nan), 0)
    precision = np.searchsorted(error, margins, side="right") / n
    # Area of the step function: precision k/N on [e_(k), e_(k+1)), with e_(N+1) = 1.
    widths = np.diff(np.r_[error, 1.0])  # (N,)
    app = float(np.sum(np.arange(1, n + 1) / n * widths))
    return PrecisionMargin(app, margins, precision.astype(np.float64), n)


def app(pred: npt.ArrayLike, true: npt.ArrayLike) -> float:
    """Area under the precision-margin curve (1 = perfect; 2/3 for chance)."""
    return precision_margin(pred, true).app


# --- helpers ---------------------------------------------------------------


def _nan_row_mean(values: FloatArray) -> FloatArray:
    """(N, K) -> (N,): mean over the finite entries of each row, NaN when none is."""
    ok = np.isfinite(values)
    count = ok.sum(axis=-1)
    total = np.where(ok, values, 0.0).sum(axis=-1)
    return np.asarray(np.where(count > 0, total / np.maximum(count, 1), np.nan), np.float64)


def _with_any(mask: npt.ArrayLike | None, per_frame: FloatArray) -> npt.NDArray[np.bool_]:
    """The caller's frame mask, less the frames that had nothing to compare."""
    ok = np.isfinite(per_frame)
    if mask is None:
        return ok
    m = np.asarray(mask, dtype=bool).reshape(-1)
    if m.shape != ok.shape:
        msg = f"mask must have {ok.size} entries, got {m.size}"
        raise ModelInputError(msg)
    return np.asarray(m & ok)


def mean_where(values: npt.ArrayLike, mask: npt.ArrayLike | None) -> float:
    """Mean of ``values`` where ``mask`` holds and the value is finite; NaN over none.

    With ``position_error_m`` or ``angle_error_deg`` this is MPJPE (in metres) or
    MPJAE over the frames in ``mask``.
    """
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    return _masked_mean(v, _with_any(mask, v))


def _masked_mean(values: FloatArray, mask: npt.ArrayLike | None) -> float:
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    if mask is not None:
        m = np.asarray(mask, dtype=bool).reshape(-1)
        if m.shape != v.shape:
            msg = f"mask must have {v.size} entries, got {m.size}"
            raise ModelInputError(msg)
        v = v[m]
    return float(v.mean()) if v.size else float("nan")


def _pair_of_poses(pred: npt.ArrayLike, true: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    p = np.asarray(pred, dtype=np.float64)
    t = np.asarray(true, dtype=np.float64)
    if p.shape != t.shape or p.shape[-2:] != (NUM_KEYPOINTS, 3):
        msg = f"poses must both be (..., {NUM_KEYPOINTS}, 3), got {p.shape} and {t.shape}"
        raise ModelInputError(msg)
    return p.reshape(-1, NUM_KEYPOINTS, 3), t.reshape(-1, NUM_KEYPOINTS, 3)


def _pair_of_actions(
    pred: npt.ArrayLike, true: npt.ArrayLike
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    p, t = np.asarray(pred), np.asarray(true)
    if p.shape != t.shape or p.ndim != 1:
        msg = f"actions must both be (N,), got {p.shape} and {t.shape}"
        raise ModelInputError(msg)
    if not (np.issubdtype(p.dtype, np.integer) and np.issubdtype(t.dtype, np.integer)):
        msg = "actions must be integer indices (take argmax of the logits first)"
        raise ModelInputError(msg)
    return p.astype(np.int64), t.astype(np.int64)


def _pair_of_progress(pred: npt.ArrayLike, true: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    p = np.asarray(pred, dtype=np.float64).reshape(-1)
    t = np.asarray(true, dtype=np.float64).reshape(-1)
    if p.shape != t.shape:
        msg = f"progress arrays differ in length: {p.size} and {t.size}"
        raise ModelInputError(msg)
    return p, t
