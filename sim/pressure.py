"""Plantar pressure from a motion: foot loads, centre of pressure, taxel maps.

Three steps, each vectorised over frames:

1. :func:`foot_loads` - how much of the body's weight each foot carries and
   where on the foot it presses. The total vertical load is
   ``m * (g + a_z)`` with ``a_z`` the COM's vertical acceleration (second
   finite difference, smoothed); it is shared between the feet in contact by
   inverse horizontal distance from the COM to each foot's centre of
   pressure (the lever rule for a COM between the feet). A foot whose
   keypoints are off the floor carries nothing; with both off (flight) the
   load is zero. Along the foot the COP follows the foot's pitch: heel only
   on the floor -> heel, toes only -> forefoot, rolling onto the hallux as
   the heel rises; flat -> under the COM's projection. Across the foot it
   rolls to the edge the COM leans over (side walking).
2. :class:`PressureRenderer` - each foot's load as a sum of regional blobs
   (:mod:`scotti.sim.foot_mask`) weighted by the COP, in newtons per taxel,
   summing exactly to the foot's load.
3. :func:`counts_from_kpa` - the sensor's transfer curve to 12-bit counts.

Deterministic and noise-free: noise exists only as a named effect.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
from scotti.models.contract import FRAME_COLS, FRAME_ROWS, KP, MAX_COUNT

# The count scale is the model's contract (importers put other sensors on it too).
from scotti.models.insole import DEFAULT_TRANSFER as DEFAULT_TRANSFER
from scotti.models.insole import INSOLE_WIDTH_RATIO, insole_mask
from scotti.models.insole import Transfer as Transfer
from scotti.models.insole import counts_from_kpa as counts_from_kpa
from scotti.sim.foot_mask import (
    REGION_BASE,
    REGION_MEDIAL,
    REGION_U,
    insole_length_m,
    region_basis,
)

G: Final = 9.81  # m/s^2

# Feet in the order the frames carry them: 0 left, 1 right (firmware Foot).
_HEEL: Final = (KP["left_heel"], KP["right_heel"])
_BIG_TOE: Final = (KP["left_big_toe"], KP["right_big_toe"])
_SMALL_TOE: Final = (KP["left_small_toe"], KP["right_small_toe"])

# A foot keypoint is on the floor below CONTACT_FULL_M and off above
# CONTACT_NONE_M (linear in between, which softens touch-down and lift-off).
CONTACT_FULL_M: Final = 0.015
CONTACT_NONE_M: Final = 0.040
# COP along the foot (0 heel, 1 hallux tip) for heel-only and flat contact.
_COP_HEEL: Final = 0.10
_COP_FLAT_RANGE: Final = (0.15, 0.80)
# Toes-only contact: the metatarsal heads at first, rolling onto the hallux as
# the foot pitches up (sine of the pitch from the first to the second value).
_COP_FOREFOOT: Final = 0.70
_COP_HALLUX: Final = 0.92
_PITCH_SIN_ROLL: Final = (0.15, 0.70)
# The COP's reach along the foot (the outermost regions' centres) and the
# bisection for the tilt that puts it there.
_COP_REACH: Final = (float(REGION_U.min()) + 0.01, float(REGION_U.max()) - 0.01)
_TILT_MAX: Final = 80.0
_TILT_ITERATIONS: Final = 24
# Across the foot: the COM this far medial of the foot is neutral (normal
# stance width); the roll saturates over the given scale.
_NEUTRAL_MEDIAL_M: Final = 0.09
_ROLL_SCALE_M: Final = 0.12
_ROLL_GAIN: Final = 2.0
# Inverse-distance sharing: distances below this do not dominate.
_SHARE_EPS_M: Final = 0.03


def _softmax(logits: np.ndarray) -> np.ndarray:
    e = np.exp(logits - logits.max(axis=-1, keepdims=True))
    return np.asarray(e / e.sum(axis=-1, keepdims=True))


@dataclass(frozen=True)
class FootLoads:
    """Per frame and foot (axis 1: 0 left, 1 right)."""

    load_n: np.ndarray  # (N, 2) vertical force on the foot
    cop_u: np.ndarray  # (N, 2) along the foot, 0 heel .. 1 toes
    cop_medial: np.ndarray  # (N, 2) -1 lateral edge .. +1 medial edge
    contact: np.ndarray  # (N, 2) 0 in the air .. 1 on the floor
    total_n: np.ndarray  # (N,) m (g + a_z), before the contact gate


def _ramp_down(z: np.ndarray) -> np.ndarray:
    """1 at/below CONTACT_FULL_M, 0 at/above CONTACT_NONE_M."""
    return np.clip((CONTACT_NONE_M - z) / (CONTACT_NONE_M - CONTACT_FULL_M), 0.0, 1.0)


def vertical_acceleration(com_z: np.ndarray, rate_hz: float) -> np.ndarray:
    """COM vertical acceleration (m/s^2): central second difference, smoothed [1 2 1]/4."""
    z = np.asarray(com_z, dtype=np.float64)
    if z.size < 3:
        return np.zeros_like(z)
    padded = np.concatenate([z[:1], z, z[-1:]])
    acc = (padded[2:] - 2.0 * padded[1:-1] + padded[:-2]) * rate_hz * rate_hz
    acc_padded = np.concatenate([acc[:1], acc, acc[-1:]])
    return 0.25 * acc_padded[:-2] + 0.5 * acc_padded[1:-1] + 0.25 * acc_padded[2:]


def foot_loads(
    keypoints: np.ndarray,
    com: np.ndarray,
    rate_hz: float,
    mass_kg: float,
    ground_z: np.ndarray | None = None,
) -> FootLoads:
    """Loads and centres of pressure of both feet.

    ``keypoints`` (N, 19, 3) world, ``com`` (N, 3); ``ground_z`` (N, 2): the
    surface height under each foot (a step), None for a flat floor.
    """
    kp = np.asarray(keypoints, dtype=np.float64)
    com = np.asarray(com, dtype=np.float64)
    ground = np.zeros((len(kp), 2)) if ground_z is None else np.asarray(ground_z, np.float64)
    heel = kp[:, _HEEL, :]  # (N, 2, 3)
    toe = 0.5 * (kp[:, _BIG_TOE, :] + kp[:, _SMALL_TOE, :])  # (N, 2, 3)
    toe_z = np.minimum(kp[:, _BIG_TOE, 2], kp[:, _SMALL_TOE, 2]) - ground
    heel_z = heel[..., 2] - ground
    c_heel, c_toe = _ramp_down(heel_z), _ramp_down(toe_z)
    contact = np.maximum(c_heel, c_toe)

    # Foot axis on the floor, heel -> toes, and the medial direction:
    # to the right of the left foot, to the left of the right foot.
    axis = toe[..., :2] - heel[..., :2]
    length = np.maximum(np.linalg.norm(axis, axis=-1), 1e-3)
    fwd = axis / length[..., None]
    left_of_foot = np.stack([-fwd[..., 1], fwd[..., 0]], axis=-1)
    medial_dir = left_of_foot * np.array([-1.0, 1.0])[None, :, None]

    rel = com[:, None, :2] - heel[..., :2]  # (N, 2, 2)
    u_com = np.einsum("nfk,nfk->nf", rel, fwd) / length
    u_flat = np.clip(u_com, *_COP_FLAT_RANGE)
    pitch_sin = (heel_z - toe_z) / np.maximum(np.linalg.norm(toe - heel, axis=-1), 1e-3)
    lo, hi = _PITCH_SIN_ROLL
    heel_rise = np.clip((pitch_sin - lo) / (hi - lo), 0.0, 1.0)
    # On the toes the COP is under the forefoot, as near the COM as it can be.
    u_pitch = _COP_FOREFOOT + (_COP_HALLUX - _COP_FOREFOOT) * heel_rise
    u_toe = np.clip(np.maximum(u_pitch, u_com), _COP_FOREFOOT, _COP_HALLUX)
    w_flat = c_heel * c_toe
    w_heel = c_heel * (1.0 - c_toe)
    w_toe = c_toe * (1.0 - c_heel)
    w_sum = w_flat + w_heel + w_toe
    cop_u = np.where(
        w_sum > 0,
        (w_flat * u_flat + w_heel * _COP_HEEL + w_toe * u_toe) / np.maximum(w_sum, 1e-12),
        0.5 * sum(_COP_FLAT_RANGE),
    )

    # COP point on the floor, then the COM's medial offset from it.
    cop_xy = heel[..., :2] + axis * cop_u[..., None]
    medial_off = np.einsum("nfk,nfk->nf", com[:, None, :2] - cop_xy, medial_dir)
    cop_medial = np.tanh((medial_off - _NEUTRAL_MEDIAL_M) / _ROLL_SCALE_M)

    # Share by inverse horizontal distance (the lever rule between two feet).
    dist = np.linalg.norm(com[:, None, :2] - cop_xy, axis=-1)
    share = contact / (dist + _SHARE_EPS_M)
    share_sum = share.sum(axis=1, keepdims=True)
    share = np.where(share_sum > 0, share / np.maximum(share_sum, 1e-12), 0.0)

    total = mass_kg * (G + vertical_acceleration(com[:, 2], rate_hz))
    gate = np.minimum(1.0, contact.sum(axis=1))
    load = np.maximum(total * gate, 0.0)[:, None] * share
    return FootLoads(load, cop_u, cop_medial, contact, total)


def to_uint16(counts: np.ndarray) -> np.ndarray:
    """Round float counts to the wire's unsigned 12-bit samples."""
    return np.asarray(np.clip(np.rint(counts), 0, MAX_COUNT), dtype=np.uint16)


class PressureRenderer:
    """Renders foot loads into per-taxel forces and pressures for one subject."""

    def __init__(self, foot_length_m: float) -> None:
        self.foot_length_m = foot_length_m
        length = insole_length_m(foot_length_m)
        taxel_area_m2 = (length / FRAME_ROWS) * (INSOLE_WIDTH_RATIO * length / FRAME_COLS)
        self.kpa_per_newton = 1e-3 / taxel_area_m2
        self.mask = insole_mask()
        self._basis = region_basis(foot_length_m).reshape(len(REGION_U), -1)  # (R, 704)

    def region_weights(self, cop_u: np.ndarray, cop_medial: np.ndarray) -> np.ndarray:
        """(..., R) shares of a foot's load per region, summing to 1.

        The least-committal spread with the COP where it should be: weights
        ``base * exp(lam * u + roll * medial)`` with ``lam`` found by bisection
        so that the regions' mean ``u`` equals ``cop_u`` (an exponential tilt).
        Standing, the COP between heel and forefoot thus loads both, not the
        arch between them.
        """
        target = np.clip(cop_u, _COP_REACH[0], _COP_REACH[1])[..., None]
        log_base = np.log(REGION_BASE) + _ROLL_GAIN * cop_medial[..., None] * REGION_MEDIAL
        lo = np.full_like(target, -_TILT_MAX)
        hi = np.full_like(target, _TILT_MAX)
        for _ in range(_TILT_ITERATIONS):
            lam = 0.5 * (lo + hi)
            w = _softmax(log_base + lam * REGION_U)
            too_far = (w * REGION_U).sum(axis=-1, keepdims=True) > target
            hi = np.where(too_far, lam, hi)
            lo = np.where(too_far, lo, lam)
        return _softmax(log_base + 0.5 * (lo + hi) * REGION_U)

    def forces(self, loads: FootLoads, frames: slice = slice(None)) -> np.ndarray:
        """(n, 2, 32, 22) float32 newtons per taxel; each foot's map sums to its load."""
        w = self.region_weights(loads.cop_u[frames], loads.cop_medial[frames])
        w *= loads.load_n[frames][..., None]
        n = w.shape[0]
        out = (w.reshape(n * 2, -1) @ self._basis).astype(np.float32)
        return np.asarray(out.reshape(n, 2, FRAME_ROWS, FRAME_COLS))

    def kpa(self, loads: FootLoads, frames: slice = slice(None)) -> np.ndarray:
        """(n, 2, 32, 22) float32 pressure per taxel in kPa."""
        return self.forces(loads, frames) * np.float32(self.kpa_per_newton)
