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
2. :class:`PressureRenderer` - each foot's sole (:mod:`scotti.sim.plantar`,
   shaped and placed on the insole by :mod:`scotti.sim.foot`) pressed into
   the insole by a contact model (:mod:`scotti.sim.contact`): kPa per taxel,
   carrying exactly the foot's load with its centre of pressure where asked.
3. The insole as a sensor (:mod:`scotti.sim.insole`): threshold, transfer
   curve, gain spread and saturation to 12-bit counts.

Deterministic and noise-free: noise exists only as a named effect.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
from scotti.models.contract import FRAME_COLS, FRAME_ROWS, KP
from scotti.sim.contact import Contact, SolutionTable
from scotti.sim.foot import Feet, foot_coordinates, neutral_feet
from scotti.sim.foot_mask import INSOLE_WIDTH_RATIO, insole_length_m, insole_mask, taxel_centres
from scotti.sim.plantar import COP_REACH_A, cop_target, sample_sole

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
# Across the foot: the COM this far medial of the foot is neutral (normal
# stance width); the roll saturates over the given scale.
_NEUTRAL_MEDIAL_M: Final = 0.09
_ROLL_SCALE_M: Final = 0.12
# Inverse-distance sharing: distances below this do not dominate.
_SHARE_EPS_M: Final = 0.03
# Taxels under sole points higher than this (mm) are never pressed.
_REACHABLE_MM: Final = 25.0
# The warm-start table of the contact solver: loads (N) x COP along x across.
_TABLE_LOADS_N: Final = np.geomspace(5.0, 5000.0, 14)
_TABLE_COP_U: Final = np.linspace(*COP_REACH_A, 33)
_TABLE_COP_MEDIAL: Final = np.linspace(-1.0, 1.0, 9)
_TABLE_COLD_ITERATIONS: Final = 30
_TABLE_STEP_ITERATIONS: Final = 8


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


class PressureRenderer:
    """Renders foot loads into per-taxel pressures for one subject's feet on their insoles.

    Each foot's sole (``plantar``) is sampled under every taxel through the
    foot's placement (``foot``) and pressed into the insole by the contact
    solver (``contact``), frame by frame, so that the map carries the foot's
    load with its centre of pressure where ``FootLoads`` puts it.
    """

    def __init__(self, foot_length_m: float, feet: Feet | None = None) -> None:
        self.feet = neutral_feet(foot_length_m) if feet is None else feet
        self.foot_length_m = self.feet.shape.length_m
        length = insole_length_m(self.foot_length_m)
        width = INSOLE_WIDTH_RATIO * length
        self.taxel_area_m2 = (length / FRAME_ROWS) * (width / FRAME_COLS)
        self.kpa_per_newton = 1e-3 / self.taxel_area_m2
        self.mask = insole_mask()
        u, x = taxel_centres()
        along, medial = u * length, (0.5 - x) * width
        grid = (2, FRAME_ROWS, FRAME_COLS)
        self.s_m, self.t_m = np.zeros(grid), np.zeros(grid)
        self.region = np.full(grid, -1)  # plantar region under each taxel, -1 none
        self._contacts: list[Contact] = []
        self._taxels: list[np.ndarray] = []
        self._tables: list[SolutionTable] = []
        for foot, placement in enumerate(self.feet.placement):
            s, t = foot_coordinates(along, medial, placement)
            sole = sample_sole(self.feet.shape, s, t)
            touchable = self.mask & (sole.height_mm < _REACHABLE_MM)
            self.s_m[foot], self.t_m[foot] = s, t
            self.region[foot][touchable] = sole.region[touchable]
            self._taxels.append(np.flatnonzero(touchable))
            contact = Contact(
                s[touchable],
                t[touchable],
                sole.height_mm[touchable],
                sole.stiffness[touchable],
                sole.lever_m[touchable],
                self.taxel_area_m2,
            )
            self._contacts.append(contact)
            self._tables.append(self._table(contact))

    def _table(self, contact: Contact) -> SolutionTable:
        """Solved unknowns over a grid of loads and COPs: every frame's solution, interpolated.

        Built by continuation along the foot: the middle column from a flat
        start, then each next COP station from its neighbours' solutions
        (extrapolated linearly), so every solve starts close and converges.
        """
        load_grid, v_grid = np.meshgrid(_TABLE_LOADS_N, _TABLE_COP_MEDIAL, indexing="ij")
        loads, v = load_grid.ravel(), v_grid.ravel()
        x = np.zeros((len(_TABLE_COP_U), len(loads), 3))
        middle = len(_TABLE_COP_U) // 2
        order = [*range(middle, len(_TABLE_COP_U)), *range(middle - 1, -1, -1)]
        for i in order:
            s_t, t_t = self.cop_target(np.full(len(loads), _TABLE_COP_U[i]), v)
            if i == middle:
                start, iterations = None, _TABLE_COLD_ITERATIONS
            else:
                back = -1 if i > middle else 1  # towards the middle
                start, iterations = x[i + back], _TABLE_STEP_ITERATIONS
                if abs(i + 2 * back - middle) <= abs(i - middle) - 2:  # two solved: extrapolate
                    start = 2 * x[i + back] - x[i + 2 * back]
            x[i] = contact.solve(loads, s_t, t_t, start, iterations)
        shape = (len(_TABLE_COP_U), len(_TABLE_LOADS_N), len(_TABLE_COP_MEDIAL), 3)
        table = x.reshape(shape).transpose(1, 0, 2, 3)
        return SolutionTable(_TABLE_LOADS_N, _TABLE_COP_U, _TABLE_COP_MEDIAL, table)

    def cop_target(
        self, cop_u: np.ndarray, cop_medial: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Foot coordinates (s, t) in metres the rendered COP is solved to."""
        return cop_target(self.feet.shape, cop_u, cop_medial)

    def kpa(self, loads: FootLoads, frames: slice = slice(None)) -> np.ndarray:
        """(n, 2, 32, 22) float32 pressure per taxel in kPa; each map carries its foot's load."""
        load = loads.load_n[frames]
        cop_u = np.clip(loads.cop_u[frames], *COP_REACH_A)
        cop_medial = np.clip(loads.cop_medial[frames], -1.0, 1.0)
        out = np.zeros((len(load), 2, FRAME_ROWS * FRAME_COLS), np.float32)
        parts = zip(self._contacts, self._tables, self._taxels, strict=True)
        for foot, (contact, table, taxels) in enumerate(parts):
            x = table.lookup(load[:, foot], cop_u[:, foot], cop_medial[:, foot])
            out[:, foot, taxels] = contact.pressure(x, load[:, foot])
        return out.reshape(len(load), 2, FRAME_ROWS, FRAME_COLS)

    def forces(self, loads: FootLoads, frames: slice = slice(None)) -> np.ndarray:
        """(n, 2, 32, 22) float32 newtons per taxel; each foot's map sums to its load."""
        return self.kpa(loads, frames) / np.float32(self.kpa_per_newton)
