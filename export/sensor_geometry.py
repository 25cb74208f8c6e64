"""Where a foreign sensor senses: its grid or discrete cells over our insole, both ways.

Each geometry takes our grid's pressure to the mean on each of its cells
(``down``) and puts cell values back on our grid as the importer does
(``up``). Discrete cell layouts come from ``importers.layouts`` where it
exists; without it, only grids are drawn.
"""

from __future__ import annotations

import functools
from typing import Final, Literal, Protocol

import numpy as np
from scotti.importers.grid import overlap_weights
from scotti.models.contract import FRAME_COLS, FRAME_ROWS
from scotti.models.insole import insole_mask


class Geometry(Protocol):
    """Where a sensor senses: area means of our grid's pressure, and back as an import."""

    cells: int

    def down(self, kpa: np.ndarray) -> np.ndarray:
        """(N, 32, 22) kPa on our grid -> (N, cells) the mean pressure on each cell."""
        ...

    def up(self, values: np.ndarray) -> np.ndarray:
        """(N, cells) -> (N, 32, 22) as the importer puts them on our grid (outline applied)."""
        ...


class GridGeometry:
    """A rows x cols grid over the same insole as ours (as importers.grid assumes).

    A cell reads the mean pressure over its part of our outline (it is a
    cell of an insole: nothing of it lies beyond the sole); the way back is
    ``importers.grid.GridMapper``'s, area-weighted means onto our taxels and
    our outline. Both ways together keep the force, sum(pressure x area),
    exactly.
    """

    def __init__(self, rows: int, cols: int) -> None:
        self.rows, self.cols = rows, cols
        self.cells = rows * cols
        self.along = overlap_weights(rows, FRAME_ROWS).astype(np.float32)  # (32, rows)
        self.across = overlap_weights(cols, FRAME_COLS).astype(np.float32)  # (22, cols)
        self.mask = insole_mask().astype(np.float32)
        area = self.along.T @ self.mask @ self.across  # (rows, cols): its share of the outline
        self.on_sole = area > 1e-6
        self.inv_area = np.where(self.on_sole, 1.0 / np.where(self.on_sole, area, 1.0), 0.0)
        self.inv_area = self.inv_area.astype(np.float32)

    def down(self, kpa: np.ndarray) -> np.ndarray:
        x = np.asarray(kpa, dtype=np.float32) * self.mask
        sums = self.along.T @ x @ self.across  # (N, rows, cols)
        sums *= self.inv_area
        return np.asarray(sums.reshape(-1, self.cells))

    def up(self, values: np.ndarray) -> np.ndarray:
        v = np.asarray(values, dtype=np.float32).reshape(-1, self.rows, self.cols)
        out = self.along @ v @ self.across.T  # (N, 32, 22), as GridMapper
        out *= self.mask
        return np.asarray(out)


@functools.lru_cache(maxsize=64)
def geometry_of(layout: str | None, rows: int, cols: int) -> tuple[Geometry, Geometry]:
    """The left and the right foot's geometry of a sensor (cached: the same every chunk)."""
    if layout is None:
        grid = GridGeometry(rows, cols)
        return grid, grid
    return CellGeometry(layout, "left"), CellGeometry(layout, "right")


class CellGeometry:
    """Discrete cells placed on the sole (``importers.layouts``): their means, and back.

    The way back is the importer's ``CellRenderer``: each cell's pressure over
    its part of our outline, its force as the vendor's cell area makes it.
    Both ways are linear; their matrices are read out of the renderer once
    (it applied to unit maps and unit cells).
    """

    def __init__(self, name: str, foot: Literal["left", "right"]) -> None:
        from scotti.importers import layouts

        renderer = layouts.CellRenderer(layouts.layout(name).for_foot(foot))
        self.cells = int(renderer.layout.cells)
        taxels = FRAME_ROWS * FRAME_COLS
        units = np.eye(taxels, dtype=np.float32).reshape(taxels, FRAME_ROWS, FRAME_COLS)
        self.means = np.asarray(renderer.cell_means(units), dtype=np.float32)  # (704, cells)
        spread = renderer(np.eye(self.cells, dtype=np.float32))  # (cells, 32, 22)
        self.spread = np.asarray(spread, dtype=np.float32).reshape(self.cells, taxels)

    def down(self, kpa: np.ndarray) -> np.ndarray:
        x = np.asarray(kpa, dtype=np.float32).reshape(len(kpa), -1)
        return one_thread_product(x, self.means)

    def up(self, values: np.ndarray) -> np.ndarray:
        out = one_thread_product(np.asarray(values, dtype=np.float32), self.spread)
        return out.reshape(-1, FRAME_ROWS, FRAME_COLS)


# OpenBLAS runs a product of fewer multiply-adds than about 262 000 on one thread;
# a larger one spreads over every core and, beside the training step, waits for them.
_ONE_THREAD_MACS: Final = 200_000


def one_thread_product(x: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``x (N, k) @ w (k, n)`` as a stack of products small enough for one thread each."""
    n = x.shape[0]
    rows = max(1, _ONE_THREAD_MACS // (w.shape[0] * w.shape[1]))
    pad = (-n) % rows
    if pad:
        x = np.concatenate([x, np.zeros((pad, x.shape[1]), dtype=x.dtype)])
    out = np.matmul(x.reshape(-1, rows, x.shape[1]), w).reshape(-1, w.shape[1])
    return np.asarray(out[:n])


@functools.lru_cache(maxsize=1)
def cell_layouts() -> tuple[str, ...]:
    """The discrete-cell layouts ``draw_sensor`` may draw (``importers.layouts``' shipped ones)."""
    try:
        from scotti.importers import layouts
    except ImportError:  # a checkout from before the layouts: grids only
        return ()
    return tuple(layouts.known_layouts())
