"""Discrete-cell insoles: where each cell lies on the sole, and its pressure onto our 32 x 22 grid.

A pedar-x insole reads 99 cells a foot, a Moticon OpenGo 16, the insoles of
PhysioNet's gaitpdb 8 force sensors. A ``CellLayout`` says where each cell
lies; a ``CellRenderer`` turns per-cell pressures into maps on our grid.

**Frame.** Positions are shares of the insole's sensing length and width:
``along`` 0 at the toe tip, 1 at the heel end; ``across`` 0 at the medial
edge, 1 at the lateral edge. That is our grid's orientation
(models/insole.py: row 0 at the toes, column 0 medial on BOTH feet, nothing
mirrored), so a point lies at row ``32 along``, column ``22 across``. The
shipped layouts (importers/cell_layouts/*.toml, one file each, with their
sources) keep the vendor's coordinates as published, with a ``[frame]`` that
says which vendor axis points to the toes, which to the medial edge of the
LEFT insole, and what extent spans the insole. ``for_foot`` gives a foot's
cells, in the vendor's cell order, in our frame. pedar, Moticon and gaitpdb
all number the right insole as the mirror image of the left (cell k at the
same place on each foot: checked on their recordings, the medial arch cells
are the unloaded ones on both feet), so both feet have one layout here; a
vendor that numbers the right insole like a shifted copy of the left
(``right_mirrored = false``) gets ``across -> 1 - across`` for the right foot.

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

import dataclasses
import functools
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final, Literal, NoReturn

import numpy as np
from scotti.importers.cell_geometry import (
    SUPERSAMPLE,
    TAXELS,
    centroid,
    extents,
    fit_to_outline,
    nearest_outline_taxel,
    onto_outline,
    outline_membership,
    polygon_area,
    tile_membership,
)
from scotti.importers.errors import ImporterError, InputError
from scotti.models.contract import FRAME_COLS, FRAME_ROWS
from scotti.models.insole import INSOLE_WIDTH_RATIO

Foot = Literal["left", "right"]
LAYOUT_DIR: Final = Path(__file__).with_name("cell_layouts")
_AXES: Final = ("+x", "-x", "+y", "-y")


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
    vendor gives newtons of sparse sensors (module docstring).
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
                self, foot=foot, centres=_frozen(onto_outline(flip(self.centres)))
            )
        fitted = fit_to_outline([flip(p) for p in self.outlines])
        outlines = tuple(_frozen(p) for p in fitted)
        covered = outline_membership(outlines).sum()
        return dataclasses.replace(
            self,
            foot=foot,
            centres=_frozen(np.array([centroid(p) for p in fitted])),
            sizes=_frozen(np.array([np.ptp(p, axis=0) for p in fitted])),
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
            areas_mm2=_frozen(areas),
            length_mm=self.length_mm * ratio**0.5,
            width_mm=self.width_mm * ratio**0.5,
            taxel_area_mm2=self.taxel_area_mm2 * ratio,
            source=f"{self.source}; areas: {note}",
        )


def known_layouts() -> tuple[str, ...]:
    """Names of the shipped layouts (importers/cell_layouts/*.toml)."""
    return tuple(sorted(p.stem for p in LAYOUT_DIR.glob("*.toml")))


def layout(name: str, size: str | None = None) -> CellLayout:
    """A shipped layout by name, or a layout file (``.toml``, as the shipped ones) by path.

    ``size``: the vendor's insole size when its cell areas depend on it
    (pedar: u, v, w, x, y, z, uw, vw, xw; Moticon: 1 .. 10); None: the
    file's ``default_size``. The left insole; ``for_foot`` for the other.
    """
    if name.endswith(".toml"):
        path = Path(name)
        if not path.is_file():
            raise InputError(path, "no such layout file")
        return _load(path, size)
    if name not in known_layouts():
        known = ", ".join(known_layouts())
        raise LayoutError(f"unknown cell layout {name!r} (known: {known}; or a .toml file)")
    return _shipped(name, size)


@functools.lru_cache(maxsize=32)
def _shipped(name: str, size: str | None) -> CellLayout:
    return _load(LAYOUT_DIR / f"{name}.toml", size)


# --- layout files -------------------------------------------------------------


def _load(path: Path, size: str | None) -> CellLayout:
    try:
        with path.open("rb") as f:
            doc = tomllib.load(f)
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise InputError(path, f"cannot read the layout ({exc})") from None
    spec = _Spec(path, doc)
    return spec.build(size)


class _Spec:
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
            outlines = tuple(_frozen(p) for p in fitted)
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
            centres=_frozen(centres),
            sizes=_frozen(
                extents(member)
                if outlines is None
                else np.array([np.ptp(p, axis=0) for p in outlines])
            ),
            areas_mm2=_frozen(areas),
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


def _frozen(a: np.ndarray) -> np.ndarray:
    out = np.array(a, dtype=np.float64)
    out.setflags(write=False)
    return out


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


# --- rendering -----------------------------------------------------------------


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


def main() -> int:
    """``python -m scotti.importers.layouts``: the shipped layouts' numbers (IMPORT.md)."""
    print("| layout | cells | size | reference insole (mm) | taxel (mm^2) | pressure kept x |")
    print("|---|---|---|---|---|---|")
    for name in known_layouts():
        cells = layout(name)
        render = CellRenderer(cells)
        factor = cells.areas_mm2 / (render.cell_taxels * cells.taxel_area_mm2)
        print(
            f"| {name} | {cells.cells} | {cells.size or '-'} | "
            f"{cells.length_mm:.0f} x {cells.width_mm:.0f} | {cells.taxel_area_mm2:.1f} | "
            f"{factor.min():.3f} .. {factor.max():.3f} |"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
