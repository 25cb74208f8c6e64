"""The insole's taxel grid (32 x 22) and the insole sizes feet wear.

Orientation, the same for both insoles, exactly as each one sends its frame:
row 0 is at the toes and row 31 at the heel; column 0 is on the MEDIAL side
(the big-toe side) and column 21 on the lateral side. Nothing is mirrored in
the data, so a left and a right frame of the same load look the same; a
viewer that wants anatomical pictures flips the left foot itself.

Geometry is in two normalised coordinates: ``u`` along the insole (0 at the
heel end, 1 at the toe end) and ``x`` across it (0 medial edge, 1 lateral).
Taxel centres sit at ``u = 1 - (row + 0.5) / 32`` and ``x = (col + 0.5) / 22``.
The outline itself is part of the model contract (models/insole.py: the
model saw zeros outside it, and importers map other insoles onto it); here
the insole (the grid) is sized to the shoe (see :func:`insole_length_m`);
the subject's foot lies in it as :mod:`scotti.sim.foot` places it.
"""

from __future__ import annotations

from typing import Final

import numpy as np
from scotti.models.insole import INSOLE_WIDTH_RATIO as INSOLE_WIDTH_RATIO
from scotti.models.insole import insole_mask as insole_mask
from scotti.models.insole import taxel_centres as taxel_centres

# Insole sizes: sensing length steps of 15 mm (about two EU sizes); the foot
# is at most this much shorter than its insole.
_SIZE_STEP_M: Final = 0.015
_SMALLEST_INSOLE_M: Final = 0.225


def insole_length_m(foot_length_m: float) -> float:
    """Sensing length of the insole a foot of this length wears (next size up)."""
    steps = np.ceil((foot_length_m - _SMALLEST_INSOLE_M) / _SIZE_STEP_M - 1e-9)
    return float(_SMALLEST_INSOLE_M + max(0.0, steps) * _SIZE_STEP_M)
