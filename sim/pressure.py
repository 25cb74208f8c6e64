"""Plantar pressure from foot loads: taxel maps in kPa.

Two steps, each vectorised over frames (the loads themselves, force and
centre of pressure per foot, come from :mod:`scotti.sim.loads`):

1. :class:`PressureRenderer` - each foot's sole (:mod:`scotti.sim.plantar`,
   shaped and placed on the insole by :mod:`scotti.sim.foot`) pressed into
   the insole by a contact model (:mod:`scotti.sim.contact`): kPa per taxel,
   carrying exactly the foot's load with its centre of pressure where asked.
2. The insole as a sensor (:mod:`scotti.sim.insole`): threshold, transfer
   curve, gain spread and saturation to 12-bit counts.

Deterministic and noise-free: noise exists only as a named effect.
"""

from __future__ import annotations

from typing import Final

import numpy as np
from scotti.models.contract import FRAME_COLS, FRAME_ROWS
from scotti.sim.contact import Contact, SolutionTable
from scotti.sim.foot import Feet, foot_coordinates, neutral_feet
from scotti.sim.foot_mask import INSOLE_WIDTH_RATIO, insole_length_m, insole_mask, taxel_centres
from scotti.sim.loads import FootLoads
from scotti.sim.plantar import COP_REACH_A, cop_target, sample_sole

# Taxels under sole points higher than this (mm) are never pressed.
_REACHABLE_MM: Final = 25.0
# The warm-start table of the contact solver: loads (N) x COP along x across.
_TABLE_LOADS_N: Final = np.geomspace(5.0, 5000.0, 14)
_TABLE_COP_U: Final = np.linspace(*COP_REACH_A, 33)
_TABLE_COP_MEDIAL: Final = np.linspace(-1.0, 1.0, 9)
_TABLE_COLD_ITERATIONS: Final = 30
_TABLE_STEP_ITERATIONS: Final = 8


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
