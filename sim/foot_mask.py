"""The insole's outline and its taxel grid (32 x 22).

Orientation, the same for both insoles, exactly as each one sends its frame:
row 0 is at the toes and row 31 at the heel; column 0 is on the MEDIAL side
(the big-toe side) and column 21 on the lateral side. Nothing is mirrored in
the data, so a left and a right frame of the same load look the same; a
viewer that wants anatomical pictures flips the left foot itself.

Geometry is in two normalised coordinates: ``u`` along the insole (0 at the
heel end, 1 at the toe end) and ``x`` across it (0 medial edge, 1 lateral).
Taxel centres sit at ``u = 1 - (row + 0.5) / 32`` and ``x = (col + 0.5) / 22``.
The insole (the grid) is sized to the shoe (see :func:`insole_length_m`);
the subject's foot lies in it as :mod:`scotti.sim.foot` places it.
"""

from __future__ import annotations

from typing import Final

import numpy as np
from scotti.models.contract import FRAME_COLS, FRAME_ROWS

# Insole outline: medial and lateral edge (x) at stations along u. A shoe
# insole: narrow rounded heel, slight medial waist, widest across the
# metatarsal heads, toe line sloping back from the big toe to the fifth.
_OUTLINE_U: Final = np.array([0.0, 0.04, 0.12, 0.30, 0.45, 0.60, 0.72, 0.84, 0.93, 1.0])
_OUTLINE_MEDIAL: Final = np.array([0.32, 0.20, 0.14, 0.17, 0.18, 0.07, 0.0, 0.0, 0.06, 0.22])
_OUTLINE_LATERAL: Final = np.array([0.68, 0.80, 0.86, 0.84, 0.86, 0.95, 1.0, 0.97, 0.72, 0.40])

# Insole sensing width as a fraction of its length (shoe insoles ~0.36-0.40).
INSOLE_WIDTH_RATIO: Final = 0.38
# Insole sizes: sensing length steps of 15 mm (about two EU sizes); the foot
# is at most this much shorter than its insole.
_SIZE_STEP_M: Final = 0.015
_SMALLEST_INSOLE_M: Final = 0.225


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
    medial = np.interp(u, _OUTLINE_U, _OUTLINE_MEDIAL)
    lateral = np.interp(u, _OUTLINE_U, _OUTLINE_LATERAL)
    return np.asarray((x >= medial) & (x <= lateral))


def insole_length_m(foot_length_m: float) -> float:
    """Sensing length of the insole a foot of this length wears (next size up)."""
    steps = np.ceil((foot_length_m - _SMALLEST_INSOLE_M) / _SIZE_STEP_M - 1e-9)
    return float(_SMALLEST_INSOLE_M + max(0.0, steps) * _SIZE_STEP_M)
