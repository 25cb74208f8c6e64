"""The insole's outline and the plantar regions on the 32 x 22 taxel grid.

Orientation, the same for both insoles, exactly as each one sends its frame:
row 0 is at the toes and row 31 at the heel; column 0 is on the MEDIAL side
(the big-toe side) and column 21 on the lateral side. Nothing is mirrored in
the data, so a left and a right frame of the same load look the same; a
viewer that wants anatomical pictures flips the left foot itself.

Geometry is in two normalised coordinates: ``u`` along the insole (0 at the
heel end, 1 at the toe end) and ``x`` across it (0 medial edge, 1 lateral).
Taxel centres sit at ``u = 1 - (row + 0.5) / 32`` and ``x = (col + 0.5) / 22``.
The insole (the grid) is sized to the shoe; the subject's foot lies in it
with the heel at the heel end and its anatomy scaled by
``foot_length / insole_length`` (see :func:`insole_length_m`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
from scotti.models.contract import FRAME_COLS, FRAME_ROWS

# The outline is the model's contract (importers mask other insoles with it too).
from scotti.models.insole import INSOLE_WIDTH_RATIO as INSOLE_WIDTH_RATIO
from scotti.models.insole import insole_mask as insole_mask
from scotti.models.insole import taxel_centres as taxel_centres

# Insole sizes: sensing length steps of 15 mm (about two EU sizes); the foot
# is at most this much shorter than its insole.
_SIZE_STEP_M: Final = 0.015
_SMALLEST_INSOLE_M: Final = 0.225


@dataclass(frozen=True)
class Region:
    """One plantar region, a Gaussian blob in foot coordinates.

    ``u``: along the FOOT (0 heel, 1 tip of the hallux); ``x``: across the
    insole (0 medial); sigmas in metres; ``base``: relative share of load the
    region takes when the centre of pressure is over it; ``medial``: -1
    lateral .. +1 medial, how the region gains when the load rolls to that
    edge.
    """

    name: str
    u: float
    x: float
    sigma_u_m: float
    sigma_x_m: float
    base: float
    medial: float


# Regions and weights after published peak-pressure maps of barefoot and
# shod gait: heel and metatarsal heads highest, hallux moderate, lateral
# midfoot low, medial arch almost unloaded.
REGIONS: Final[tuple[Region, ...]] = (
    Region("heel_medial", 0.085, 0.42, 0.018, 0.012, 1.00, 0.5),
    Region("heel_lateral", 0.085, 0.60, 0.018, 0.012, 1.00, -0.5),
    Region("midfoot_lateral", 0.38, 0.74, 0.030, 0.010, 0.30, -0.9),
    Region("arch_medial", 0.40, 0.30, 0.020, 0.008, 0.06, 0.7),
    Region("mth1", 0.70, 0.20, 0.013, 0.010, 0.95, 1.0),
    Region("mth23", 0.72, 0.47, 0.013, 0.012, 1.00, 0.1),
    Region("mth45", 0.66, 0.78, 0.013, 0.010, 0.55, -0.9),
    Region("hallux", 0.91, 0.20, 0.012, 0.010, 0.65, 1.0),
    Region("toes", 0.87, 0.58, 0.011, 0.020, 0.30, -0.4),
)
REGION_U: Final = np.array([r.u for r in REGIONS])
REGION_MEDIAL: Final = np.array([r.medial for r in REGIONS])
REGION_BASE: Final = np.array([r.base for r in REGIONS])


def insole_length_m(foot_length_m: float) -> float:
    """Sensing length of the insole a foot of this length wears (next size up)."""
    steps = np.ceil((foot_length_m - _SMALLEST_INSOLE_M) / _SIZE_STEP_M - 1e-9)
    return float(_SMALLEST_INSOLE_M + max(0.0, steps) * _SIZE_STEP_M)


def region_basis(foot_length_m: float) -> np.ndarray:
    """(R, 32, 22) float64: each region's blob on the grid, masked, summing to 1.

    Blob centres scale with the foot (heel anchored at the insole's heel end),
    so a small foot in its insole leaves the front rows lighter.
    """
    length = insole_length_m(foot_length_m)
    width = INSOLE_WIDTH_RATIO * length
    scale = foot_length_m / length
    u, x = taxel_centres()
    mask = insole_mask()
    basis = np.empty((len(REGIONS), FRAME_ROWS, FRAME_COLS))
    for i, r in enumerate(REGIONS):
        du = (u - r.u * scale) * length / r.sigma_u_m
        dx = (x - r.x) * width / r.sigma_x_m
        blob = np.exp(-0.5 * (du * du + dx * dx)) * mask
        basis[i] = blob / blob.sum()
    return basis
