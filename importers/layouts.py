"""Discrete-cell insoles: where each cell lies on the sole, and its pressure onto our 32 x 22 grid.

A pedar-x insole reads 99 cells a foot, a Moticon OpenGo 16, the insoles of
PhysioNet's gaitpdb 8 force sensors. A ``CellLayout`` says where each cell
lies; a ``CellRenderer`` turns per-cell pressures into maps on our grid.
This module finds the shipped layouts and loads one by name or path; the
parts live in importers/cell_layout.py (the layout), importers/layout_file.py
(reading and checking a layout file) and importers/cell_renderer.py (the
rendering, and why it keeps each cell's force), and are all importable from
here.

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
"""

from __future__ import annotations

import functools
import tomllib
from pathlib import Path
from typing import Final

from scotti.importers.cell_layout import CellLayout, Foot, LayoutError
from scotti.importers.cell_renderer import CellRenderer, cell_means, membership
from scotti.importers.errors import InputError
from scotti.importers.layout_file import LayoutFile

__all__ = [
    "LAYOUT_DIR",
    "CellLayout",
    "CellRenderer",
    "Foot",
    "LayoutError",
    "cell_means",
    "known_layouts",
    "layout",
    "main",
    "membership",
]

LAYOUT_DIR: Final = Path(__file__).with_name("cell_layouts")


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


def _load(path: Path, size: str | None) -> CellLayout:
    try:
        with path.open("rb") as f:
            doc = tomllib.load(f)
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise InputError(path, f"cannot read the layout ({exc})") from None
    spec = LayoutFile(path, doc)
    return spec.build(size)


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
