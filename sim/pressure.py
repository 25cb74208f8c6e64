"""Plantar pressure from foot loads: taxel maps and the sensor's transfer curve.

Two steps, each vectorised over frames:

1. :class:`PressureRenderer` - each foot's load (:mod:`scotti.sim.loads`) as a
   sum of regional blobs (:mod:`scotti.sim.foot_mask`) weighted by the COP, in
   newtons per taxel, summing exactly to the foot's load.
2. :func:`counts_from_kpa` - the sensor's transfer curve to 12-bit counts.

Deterministic and noise-free: noise exists only as a named effect.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
from scotti.models.contract import FRAME_COLS, FRAME_ROWS, MAX_COUNT
from scotti.sim.foot_mask import (
    INSOLE_WIDTH_RATIO,
    REGION_BASE,
    REGION_MEDIAL,
    REGION_U,
    insole_length_m,
    insole_mask,
    region_basis,
)
from scotti.sim.loads import FootLoads

# The COP's reach along the foot (the outermost regions' centres) and the
# bisection for the tilt that puts it there.
_COP_REACH: Final = (float(REGION_U.min()) + 0.01, float(REGION_U.max()) - 0.01)
_TILT_MAX: Final = 80.0
_TILT_ITERATIONS: Final = 24
# Across the foot: how strongly the medial COP weights the medial regions.
_ROLL_GAIN: Final = 2.0


def _softmax(logits: np.ndarray) -> np.ndarray:
    e = np.exp(logits - logits.max(axis=-1, keepdims=True))
    return np.asarray(e / e.sum(axis=-1, keepdims=True))


@dataclass(frozen=True)
class Transfer:
    """Sensor transfer curve: pressure on a taxel (kPa) -> 12-bit counts.

    A piezoresistive taxel's conductance grows about linearly with pressure;
    read through a voltage divider it gives
    ``counts = full_scale * q^k / (q^k + p_half^k)``, ``q = max(p - threshold, 0)``:
    linear for light loads, half scale at ``p_half_kpa``, saturating towards
    ``full_scale``. Clipped to MAX_COUNT. ``exponent`` 1 is the ideal divider.
    """

    p_half_kpa: float = 250.0  # pressure giving half scale (typ. 150-400 kPa)
    threshold_kpa: float = 3.0  # activation pressure, below it reads 0
    full_scale: float = float(MAX_COUNT)  # asymptote in counts (ADC rail)
    exponent: float = 1.0


DEFAULT_TRANSFER: Final = Transfer()


def counts_from_kpa(kpa: np.ndarray, transfer: Transfer = DEFAULT_TRANSFER) -> np.ndarray:
    """Float32 counts (same shape), clipped to [0, MAX_COUNT]; round when packing."""
    f32 = np.float32
    q = np.maximum(np.asarray(kpa, dtype=f32) - f32(transfer.threshold_kpa), f32(0.0))
    half = f32(transfer.p_half_kpa)
    if transfer.exponent != 1.0:
        q **= f32(transfer.exponent)
        half **= f32(transfer.exponent)
    counts: np.ndarray = np.asarray(q / (q + half), dtype=f32)
    counts *= f32(transfer.full_scale)
    np.minimum(counts, f32(MAX_COUNT), out=counts)
    return counts


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
