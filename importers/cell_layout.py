"""A discrete-cell insole's layout: where each of its cells lies on the sole, in our frame.

``CellLayout`` is the value the layout files load into (importers/layout_file.py)
and the renderer draws from (importers/cell_renderer.py); ``for_foot`` gives
the other foot's cells. The frame (along 0 at the toe tip, across 0 at the
medial edge) is explained in importers/layouts.py.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Literal

import numpy as np
from scotti.importers.cell_geometry import (
    centroid,
    fit_to_outline,
    onto_outline,
    outline_membership,
)
from scotti.importers.errors import ImporterError

Foot = Literal["left", "right"]


class LayoutError(ImporterError):
    """An unknown layout or insole size (one line, listing the known ones)."""


@dataclass(frozen=True, kw_only=True, eq=False)
class CellLayout:
    """Where each cell of a discrete-cell insole lies on the sole, in our frame.

    ``centres`` (n, 2): (along, across) shares of our grid, along 0 toe
    tip .. 1 heel end, across 0 medial .. 1 lateral edge, in the vendor's
    cell order (cell 1 first) for ``foot`` (the shipped layouts load for the
    vendor's LEFT insole; ``for_foot`` gives the other). ``sizes`` (n, 2):
    each cell's extent (along, across) in the same shares. ``outlines``: each
    cell's polygon (k, 2) fitted to our outline where the vendor's outlines
    are known, else None and the cells are ``tiled`` (each stands for its
    tile of the sole). ``areas_mm2``: each cell's area, for force = pressure
    x area. ``length_mm`` x ``width_mm``: the vendor's reference insole
    (size ``size``) as its areas imply (see ``source``); ``taxel_area_mm2``:
    one of our taxels with that insole on our grid. ``point_sensors``: the
    vendor gives newtons of sparse sensors (importers/cell_renderer.py).
    ``right_mirrored``: the vendor's right insole is the mirror image of its
    left (cell k at the same place on each foot: pedar, Moticon, gaitpdb);
    False: a shifted copy, so medial and lateral swap on the right foot.
    """

    name: str
    source: str
    centres: np.ndarray
    sizes: np.ndarray
    areas_mm2: np.ndarray
    length_mm: float
    width_mm: float
    taxel_area_mm2: float
    point_sensors: bool
    tiled: bool
    outlines: tuple[np.ndarray, ...] | None = None
    right_mirrored: bool = True
    foot: Foot = "left"
    size: str = ""  # the vendor's insole size the areas are for ("" when it has no sizes)

    def __post_init__(self) -> None:
        n = len(self.centres)
        shapes = {"centres": (n, 2), "sizes": (n, 2), "areas_mm2": (n,)}
        for field, shape in shapes.items():
            if np.shape(getattr(self, field)) != shape:
                msg = f"layout {self.name}: {field} has shape {np.shape(getattr(self, field))}, "
                raise LayoutError(msg + f"expected {shape}")
        if self.outlines is None and not self.tiled:
            raise LayoutError(f"layout {self.name}: cells without outlines must be tiled")
        if self.point_sensors and not self.tiled:
            raise LayoutError(f"layout {self.name}: point sensors are drawn over tiles")

    @property
    def cells(self) -> int:
        return len(self.centres)

    def for_foot(self, foot: Foot) -> CellLayout:
        """This foot's cells in the vendor's order, in our frame (medial at 0 on both feet)."""
        if foot not in ("left", "right"):
            raise LayoutError(f"layout {self.name}: foot {foot!r} is neither 'left' nor 'right'")
        if foot == self.foot or self.right_mirrored:
            return self if foot == self.foot else dataclasses.replace(self, foot=foot)

        # The other insole's cell k lies at the mirror image of this one's: medial
        # and lateral swap, then it is fitted to our outline as this one was.
        def flip(a: np.ndarray) -> np.ndarray:
            out = np.array(a, dtype=np.float64)
            out[:, 1] = 1.0 - out[:, 1]
            return out

        if self.outlines is None:
            return dataclasses.replace(
                self, foot=foot, centres=frozen(onto_outline(flip(self.centres)))
            )
        fitted = fit_to_outline([flip(p) for p in self.outlines])
        outlines = tuple(frozen(p) for p in fitted)
        covered = outline_membership(outlines).sum()
        return dataclasses.replace(
            self,
            foot=foot,
            centres=frozen(np.array([centroid(p) for p in fitted])),
            sizes=frozen(np.array([np.ptp(p, axis=0) for p in fitted])),
            outlines=outlines,
            taxel_area_mm2=float(self.areas_mm2.sum() / covered),
        )

    def with_areas(self, areas_mm2: np.ndarray, note: str) -> CellLayout:
        """The same cells with other areas (e.g. fitted to a file's total force).

        The reference insole is scaled with them (same shape), so the taxel
        area follows and pressures stay where they were.
        """
        areas = np.asarray(areas_mm2, dtype=np.float64)
        if areas.shape != (self.cells,) or not np.all(areas > 0):
            msg = f"layout {self.name}: {self.cells} positive areas expected, got shape "
            raise LayoutError(msg + f"{areas.shape}")
        ratio = float(areas.sum() / self.areas_mm2.sum())
        return dataclasses.replace(
            self,
            areas_mm2=frozen(areas),
            length_mm=self.length_mm * ratio**0.5,
            width_mm=self.width_mm * ratio**0.5,
            taxel_area_mm2=self.taxel_area_mm2 * ratio,
            source=f"{self.source}; areas: {note}",
        )


def frozen(a: np.ndarray) -> np.ndarray:
    """A float64 copy that cannot be written: layouts are cached and shared."""
    out = np.array(a, dtype=np.float64)
    out.setflags(write=False)
    return out
