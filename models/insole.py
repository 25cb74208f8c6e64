"""The insole behind a count: the outline of the taxel grid and the count scale.

Both belong to the contract the shipped model learnt: it saw zeros outside
this outline and pressures mapped onto counts by this transfer curve. The
simulator renders through them (sim/pressure.py, sim/foot_mask.py) and the
importers (importers/) put other insoles' recordings onto them, so both
read from here.

Orientation, the same for both insoles: row 0 at the toes, row 31 at the
heel; column 0 on the MEDIAL side (big toe), column 21 lateral. Outline
coordinates: ``u`` along the insole (0 heel end, 1 toe end), ``x`` across
(0 medial edge, 1 lateral); taxel centres at ``u = 1 - (row + 0.5) / 32``
and ``x = (col + 0.5) / 22``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
from scotti.models.contract import FRAME_COLS, FRAME_ROWS, MAX_COUNT

# Insole outline: medial and lateral edge (x) at stations along u. A shoe
# insole: narrow rounded heel, slight medial waist, widest across the
# metatarsal heads, toe line sloping back from the big toe to the fifth.
OUTLINE_U: Final = np.array([0.0, 0.04, 0.12, 0.30, 0.45, 0.60, 0.72, 0.84, 0.93, 1.0])
OUTLINE_MEDIAL: Final = np.array([0.32, 0.20, 0.14, 0.17, 0.18, 0.07, 0.0, 0.0, 0.06, 0.22])
OUTLINE_LATERAL: Final = np.array([0.68, 0.80, 0.86, 0.84, 0.86, 0.95, 1.0, 0.97, 0.72, 0.40])

# Insole sensing width as a fraction of its length (shoe insoles ~0.36-0.40).
INSOLE_WIDTH_RATIO: Final = 0.38


def taxel_centres() -> tuple[np.ndarray, np.ndarray]:
    """(u, x) of every taxel centre, each (FRAME_ROWS, FRAME_COLS)."""
    u = 1.0 - (np.arange(FRAME_ROWS) + 0.5) / FRAME_ROWS
    x = (np.arange(FRAME_COLS) + 0.5) / FRAME_COLS
    return np.broadcast_to(u[:, None], (FRAME_ROWS, FRAME_COLS)), np.broadcast_to(
        x[None, :], (FRAME_ROWS, FRAME_COLS)
    )


def insole_mask() -> np.ndarray:
    """Bool (32, 22): True where the insole has a taxel (inside its outline)."""
    u, x = taxel_centres()
    medial = np.interp(u, OUTLINE_U, OUTLINE_MEDIAL)
    lateral = np.interp(u, OUTLINE_U, OUTLINE_LATERAL)
    return np.asarray((x >= medial) & (x <= lateral))


@dataclass(frozen=True)
class Transfer:
    """Sensor transfer curve: pressure on a taxel (kPa) -> 12-bit counts.

    A piezoresistive film's conductance grows as a power of the pressure and
    a voltage divider reads it, so
    ``counts = 4095 * q^n / (q^n + p_half^n)``, ``q = p - threshold`` (0 below
    the activation threshold), clipped where the amplifier rails
    (``saturation_counts``). The defaults are the simulator's ``realistic``
    insole (sim/insole.py, which draws per-insole variations around them):
    the count scale the shipped model learnt, and the one importers map other
    sensors' kPa onto.
    """

    p_half_kpa: float = 180.0  # pressure above threshold reading half of full scale
    threshold_kpa: float = 20.0  # activation pressure, below it a taxel reads 0
    exponent: float = 0.8  # power of the film's conductance law (1: ideal divider)
    saturation_counts: float = 3800.0  # where the amplifier rails (<= MAX_COUNT)


DEFAULT_TRANSFER: Final = Transfer()


def counts_from_kpa(kpa: np.ndarray, transfer: Transfer = DEFAULT_TRANSFER) -> np.ndarray:
    """Float32 counts of pressures (same shape), clipped to the rail; round when packing.

    Only pressed taxels are computed (most of an insole reads 0 most of the time).
    """
    f32 = np.float32
    q = np.asarray(kpa, dtype=f32) - f32(transfer.threshold_kpa)
    pressed = q > 0.0
    counts = np.zeros(q.shape, f32)
    v = q[pressed]
    half = f32(transfer.p_half_kpa)
    if transfer.exponent != 1.0:
        v **= f32(transfer.exponent)
        half **= f32(transfer.exponent)
    v /= v + half
    v *= f32(MAX_COUNT)
    np.minimum(v, f32(min(transfer.saturation_counts, MAX_COUNT)), out=v)
    counts[pressed] = v
    return counts
