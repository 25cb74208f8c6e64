"""A layout file (importers/cell_layouts/*.toml, or a user's): read, checked, made a ``CellLayout``.

The file keeps the vendor's coordinates as published, with a ``[frame]``
saying which vendor axis points to the toes and which to the medial edge of
the LEFT insole (importers/layouts.py: the frame). ``LayoutFile`` checks it
field by field, so every mistake is one line naming the file and the key,
then places the cells on our outline and works out the reference insole
their areas imply.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Final, NoReturn

import numpy as np
from scotti.importers.cell_geometry import (
    TAXELS,
    centroid,
    extents,
    fit_to_outline,
    onto_outline,
    outline_membership,
    polygon_area,
    tile_membership,
)
from scotti.importers.cell_layout import CellLayout, LayoutError, frozen
from scotti.importers.errors import InputError
from scotti.models.insole import INSOLE_WIDTH_RATIO

_AXES: Final = ("+x", "-x", "+y", "-y")


class LayoutFile:
    """One layout file, checked field by field; every mistake names the file and the key."""

    def __init__(self, path: Path, doc: dict[str, Any]) -> None:
        self.path, self.doc = path, doc
        self.name = self.text("name")
        self.note = ""  # what the source does not say about the chosen size
        self.source = self.text("source")
        self.point_sensors = self.flag("point_sensors", False)
        self.tiled = self.flag("tiled", self.point_sensors)
        self.right_mirrored = self.flag("right_mirrored", True)
        frame = self.table("frame")
        self.toe, self.medial = self.axis(frame, "toe"), self.axis(frame, "medial")
        if self.toe[1] == self.medial[1]:
            self.fail("frame: toe and medial must be different axes (x and y)")
        self.to_scale = bool(frame.get("to_scale", False))
        cells = self.table("cells")
        if ("outlines" in cells) == ("points" in cells):
            self.fail("cells: give either outlines (polygons) or points (tiled)")
        if "outlines" in cells:
            self.raw = [
                self.points(o, f"cells.outlines[{i}]") for i, o in enumerate(cells["outlines"])
            ]
            if any(len(o) < 3 for o in self.raw):
                self.fail("cells.outlines: a polygon needs at least 3 corners")
        else:
            self.raw = [
                self.points([p], f"cells.points[{i}]") for i, p in enumerate(cells["points"])
            ]
            self.tiled = True
        if not self.raw:
            self.fail("cells: no cells")
        self.bounds = self.extent(frame.get("bounds", "cells"))

    def fail(self, problem: str) -> NoReturn:
        raise InputError(self.path, problem)

    def text(self, key: str) -> str:
        value = self.doc.get(key)
        if not isinstance(value, str) or not value.strip():
            self.fail(f"{key}: a text is required")
        return str(value).strip()

    def flag(self, key: str, default: bool) -> bool:
        value = self.doc.get(key, default)
        if not isinstance(value, bool):
            self.fail(f"{key}: true or false, not {value!r}")
        return bool(value)

    def table(self, key: str) -> dict[str, Any]:
        value = self.doc.get(key)
        if not isinstance(value, dict):
            self.fail(f"[{key}] is required")
        return dict(value)

    def axis(self, frame: dict[str, Any], key: str) -> str:
        value = frame.get(key)
        if value not in _AXES:
            self.fail(f"frame.{key}: one of {', '.join(_AXES)}, not {value!r}")
        return str(value)

    def points(self, value: Any, where: str) -> np.ndarray:
        try:
            a = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            a = np.empty(0)
        if a.ndim != 2 or a.shape[1] != 2 or not np.isfinite(a).all():
            self.fail(f"{where}: expected [x, y] number pairs")
        return a

    def extent(self, value: Any) -> tuple[float, float, float, float]:
        if value == "cells":
            every = np.concatenate(self.raw)
            lo, hi = every.min(axis=0), every.max(axis=0)
            if self.tiled:
                self.fail("frame.bounds: tiled layouts need explicit [xmin, xmax, ymin, ymax]")
            return float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1])
        try:
            x0, x1, y0, y1 = (float(v) for v in value)
        except (TypeError, ValueError):
            self.fail('frame.bounds: "cells" or [xmin, xmax, ymin, ymax]')
        if not (x1 > x0 and y1 > y0):
            self.fail("frame.bounds: [xmin, xmax, ymin, ymax] with xmax > xmin and ymax > ymin")
        return x0, x1, y0, y1

    def ours(self, pts: np.ndarray) -> np.ndarray:
        """Vendor (x, y) -> our (along, across) shares, for the left insole."""
        x0, x1, y0, y1 = self.bounds
        span = {"x": (x0, x1), "y": (y0, y1)}
        col = {"x": 0, "y": 1}

        def share(axis: str, towards_zero: bool) -> np.ndarray:
            lo, hi = span[axis]
            v = pts[:, col[axis]]
            return (hi - v) / (hi - lo) if towards_zero else (v - lo) / (hi - lo)

        along = share(self.toe[1], self.toe[0] == "+")  # the toe end is along 0
        across = share(self.medial[1], self.medial[0] == "+")  # the medial edge is across 0
        return np.stack([along, across], axis=1)

    def aspect(self) -> float:
        """Width / length of the reference insole."""
        if not self.to_scale:
            return INSOLE_WIDTH_RATIO
        x0, x1, y0, y1 = self.bounds
        spans = {"x": x1 - x0, "y": y1 - y0}
        return spans[self.medial[1]] / spans[self.toe[1]]

    def areas(self, size: str | None, n: int) -> tuple[np.ndarray | None, str]:
        table = self.doc.get("areas_mm2")
        if table is None:
            if size is not None:
                raise LayoutError(f"layout {self.name} has no insole sizes (size {size!r})")
            return None, ""
        if not isinstance(table, dict) or not table:
            self.fail("areas_mm2: a table of size = [one area per cell]")
        chosen = str(self.doc.get("default_size", next(iter(table)))) if size is None else size
        if chosen in table:
            values = np.asarray(table[chosen], dtype=np.float64)
            if values.shape != (n,) or not np.all(values > 0):
                self.fail(f"areas_mm2.{chosen}: {n} positive areas expected")
            return values, chosen
        return self.scaled_areas(table, chosen, n), chosen

    def scaled_areas(self, table: dict[str, Any], size: str, n: int) -> np.ndarray:
        """Areas of an unlisted numbered size, from ``size_area_ratio`` per size step.

        Said in the layout's ``source`` (``self.note``): they are extrapolated.
        """
        ratio = self.doc.get("size_area_ratio")
        listed = [k for k in table if k.isdigit()]
        if not isinstance(ratio, float) or not size.isdigit() or not listed:
            known = ", ".join(table)
            raise LayoutError(f"layout {self.name} has no size {size!r} (known: {known})")
        base = min(listed, key=lambda k: abs(int(k) - int(size)))
        values = np.asarray(table[base], dtype=np.float64)
        if values.shape != (n,):
            self.fail(f"areas_mm2.{base}: {n} areas expected")
        self.note = f"; size {size} not listed: areas of size {base} x {ratio:g} per size step"
        return np.asarray(values * ratio ** (int(size) - int(base)))

    def build(self, size: str | None) -> CellLayout:
        n = len(self.raw)
        aspect = self.aspect()
        areas, size_name = self.areas(size, n)
        if areas is None and not self.tiled:
            self.fail("areas_mm2 is required for cells with outlines")
        outlines: tuple[np.ndarray, ...] | None = None
        if self.tiled:
            centres = onto_outline(self.ours(np.concatenate(self.raw)))
            member = tile_membership(centres, aspect, areas)
        else:
            fitted = fit_to_outline([self.ours(p) for p in self.raw])
            outlines = tuple(frozen(p) for p in fitted)
            centres = np.array([centroid(p) for p in fitted])
            member = outline_membership(outlines)
        covered = member.sum(axis=0)  # taxels' worth of each cell on our grid
        if areas is None:  # point sensors: each tile's area on a nominal insole
            length = self.number("length_mm")
            taxel_mm2 = length * aspect * length / TAXELS
            areas = covered * taxel_mm2
        else:
            # One taxel is the vendor's sensing area over the taxels it covers
            # here, so a cell's pressure stays as the vendor read it on average.
            taxel_mm2 = float(areas.sum() / covered.sum())
            length = self.vendor_length(areas, aspect, taxel_mm2)
        return CellLayout(
            name=self.name,
            source=self.source + self.note,
            centres=frozen(centres),
            sizes=frozen(
                extents(member)
                if outlines is None
                else np.array([np.ptp(p, axis=0) for p in outlines])
            ),
            areas_mm2=frozen(areas),
            length_mm=length,
            width_mm=aspect * length,
            taxel_area_mm2=taxel_mm2,
            point_sensors=self.point_sensors,
            tiled=self.tiled,
            outlines=outlines,
            right_mirrored=self.right_mirrored,
            size=size_name,
        )

    def vendor_length(self, areas: np.ndarray, aspect: float, taxel_mm2: float) -> float:
        """The sensing length the cells' areas imply.

        Cells with outlines drawn to scale: the drawing scaled until its cells'
        area is the listed one. Otherwise our outline holding that area.
        """
        if self.tiled or not self.to_scale:
            return float(np.sqrt(taxel_mm2 * TAXELS / aspect))
        drawn = sum(polygon_area(p) for p in self.raw)  # vendor units^2
        scale = float(np.sqrt(areas.sum() / drawn))  # mm per vendor unit
        x0, x1, y0, y1 = self.bounds
        return scale * ((y1 - y0) if self.toe[1] == "y" else (x1 - x0))

    def number(self, key: str) -> float:
        value = self.doc.get(key)
        if not isinstance(value, (int, float)) or isinstance(value, bool) or value <= 0:
            self.fail(f"{key}: a positive number is required")
        return float(value)
