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
