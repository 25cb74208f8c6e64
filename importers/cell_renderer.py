"""Discrete cells onto our 32 x 22 grid and back: which taxels each cell covers, and its force kept.

A ``CellRenderer`` turns per-cell pressures of a ``CellLayout``
(importers/cell_layout.py) into maps on our grid, and ``cell_means`` a map
into per-cell pressures.

**Rendering** (``CellRenderer``), and why:

1. The vendor's insole is taken to span ours, as importers/grid.py does for
   dense grids: both carry the same foot, and the model reads pressure,
   which scaling an insole does not change. Cells with outlines (pedar) are
   fitted to our outline station by station along the foot: at each
   station the cells' joint medial..lateral span is stretched onto ours
   (importers/cell_geometry.py ``fit_to_outline``). A plain box scaling
   would leave pedar's straight lateral hindfoot edge outside ours, and
   cells with 4 % of their area on our grid.
2. Membership: each of our taxels is split into 8 x 8 points, and each
   point goes to the cell whose outline holds it, so a taxel on a cell's
   edge is shared by area. Taxels outside our outline (``insole_mask``) are
   dropped: the model never saw pressure there. A cell that would cover
   none of our taxels goes to the taxel of our outline nearest its centre.
3. Tiled layouts (Moticon, gaitpdb): the sensors leave gaps, but the
   vendor's numbers stand for the whole sole. Moticon's exported total
   force is sum(pressure x area) with areas that include the gaps (its
   "area factors"); gaitpdb's 8 forces add up to the file's total-force
   column, which averages about body weight over a gait cycle. So each
   sensor is drawn over its tile of the sole: the points of our outline go
   to the nearest sensor (distance in millimetres) with a soft edge
   (softmax of ``(w_i - d^2) / 2 s^2``, ``s`` 0.3 of the sensors' median
   spacing), so that a map is a sole rather than flat plates; where the
   vendor gives areas, the weights ``w_i`` size each tile to its area (a
   power diagram), so the tiles are the regions those areas stand for. A
   sensor whose position falls on a taxel outside our outline is moved to
   the nearest taxel inside it (Moticon's sensor 8, by one taxel: its
   insole's lateral mid-foot is wider than ours).
4. Force kept per cell: ``weights[t, i] = m[t, i] area_i / (a sum_t m[t, i])``
   with ``m`` the membership and ``a`` the taxel area, so that
   ``sum_t p_t a == p_i area_i`` for every cell, including one cut by our
   outline (its force goes to its part inside). ``a`` is the vendor's
   sensing area (the cells' areas) over the taxels the cells cover here,
   so on average a cell's pressure stays as the vendor read it; per cell
   it moves by ``area_i / (a sum_t m[t, i])``: 1.00 +- 0.005 for Moticon
   and gaitpdb (tiles sized to the areas), 0.75 .. 1.29 for pedar, whose
   drawn outlines differ from its listed areas (-11 .. +16 %) and whose
   round heel meets our blunter one.
5. ``cell_means`` is the inverse sampling: the membership-weighted mean of a
   map over each cell. A uniform map gives each cell that pressure, and a
   simulated map seen "through" a foreign insole is
   ``renderer(renderer.cell_means(map))``.

**Point sensors** (gaitpdb, ``point_sensors``): newtons per sensor, no
published sensing area, sensor positions "approximate" (format.txt) in
arbitrary units. Each sensor's ``areas_mm2`` is the area of its tile on a
nominal insole (``length_mm``), so a reader that divides a sensor's force by
it gets a map whose tile carries that force and whose foot total equals the
file's total column. The force is thus kept per tile, not per physical
sensor: the real sensors are small and their loads are calibrated to stand
for the foot. The map holds a tile's mean pressure (no peaks under the
sensors), and it depends on the nominal size: a reader rescales each foot's
total to the file's own total-force column.
"""

from __future__ import annotations

import numpy as np
from scotti.importers.cell_geometry import (
    SUPERSAMPLE,
    TAXELS,
    nearest_outline_taxel,
    outline_membership,
    tile_membership,
)
from scotti.importers.cell_layout import CellLayout, LayoutError
from scotti.models.contract import FRAME_COLS, FRAME_ROWS


def membership(cells: CellLayout, supersample: int = SUPERSAMPLE) -> np.ndarray:
    """(704, n) share of each of our taxels that belongs to each cell, our outline applied.

    A cell that would cover none of our taxels gets the taxel of our outline
    nearest its centre, so every cell reaches the grid.
    """
    if cells.outlines is not None:
        member = outline_membership(cells.outlines, supersample)
    else:
        aspect = cells.width_mm / cells.length_mm
        member = tile_membership(np.asarray(cells.centres), aspect, cells.areas_mm2, supersample)
    member = np.asarray(member, dtype=np.float64)
    for i in np.flatnonzero(member.sum(axis=0) <= 0):
        member[nearest_outline_taxel(cells.centres[i]), i] = 1.0
    return member


class CellRenderer:
    """(N, n) per-cell pressure in kPa -> (N, 32, 22) kPa on our grid, keeping each cell's force.

    ``weights`` (704, n) is precomputed, so a render is one matrix product:
    ``sum over taxels of p x taxel_area == cell pressure x cell area`` for
    every cell (module docstring: why, and what tiled and point-sensor
    layouts do). ``cell_means`` goes the other way.
    """

    def __init__(self, layout: CellLayout) -> None:
        self.layout = layout
        member = membership(layout)
        covered = member.sum(axis=0)  # (n,) taxels' worth of each cell on our grid
        self.membership = member.astype(np.float32)  # (704, n) share of each taxel in each cell
        self.cell_taxels = covered
        per_cell = np.asarray(layout.areas_mm2) / (layout.taxel_area_mm2 * covered)
        self.weights = (member * per_cell).astype(np.float32)  # (704, n)
        self._means = (member / covered).astype(np.float32)  # (704, n) columns sum to 1

    def __call__(self, kpa: np.ndarray) -> np.ndarray:
        x = self._cells(kpa, "kpa")
        return np.asarray((x @ self.weights.T).reshape(-1, FRAME_ROWS, FRAME_COLS))

    def cell_means(self, kpa_grid: np.ndarray) -> np.ndarray:
        """(N, 32, 22) kPa -> (N, n): the mean pressure of the map over each cell."""
        grid = np.asarray(kpa_grid, dtype=np.float32)
        if grid.ndim != 3 or grid.shape[1:] != (FRAME_ROWS, FRAME_COLS):
            msg = f"{self.layout.name}: maps must be (N, {FRAME_ROWS}, {FRAME_COLS}), "
            raise LayoutError(msg + f"not {grid.shape}")
        return np.asarray(grid.reshape(len(grid), TAXELS) @ self._means)

    def force_n(self, kpa: np.ndarray) -> np.ndarray:
        """(N, n) cell pressures in kPa -> (N,) the foot's force in newtons (vendor areas)."""
        x = self._cells(kpa, "kpa")
        return np.asarray(x @ (np.asarray(self.layout.areas_mm2, np.float32) * np.float32(1e-3)))

    def _cells(self, kpa: np.ndarray, what: str) -> np.ndarray:
        x = np.asarray(kpa, dtype=np.float32)
        if x.ndim != 2 or x.shape[1] != self.layout.cells:
            msg = f"{self.layout.name}: {what} must be (N, {self.layout.cells}), not {x.shape}"
            raise LayoutError(msg)
        return x


def cell_means(cells: CellLayout, kpa_grid: np.ndarray) -> np.ndarray:
    """(N, 32, 22) kPa -> (N, n) mean pressure over each cell (for one call; else a renderer)."""
    return CellRenderer(cells).cell_means(kpa_grid)
