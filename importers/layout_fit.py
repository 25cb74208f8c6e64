"""Cell areas and positions from a vendor's own totals: ``python -m scotti.importers.layout_fit``.

An insole that exports, beside its cell pressures, the foot's total force
and centre of pressure (Moticon OpenGo does) says through them where its
cells are and how large each counts:

- total force ``F = sum_i p_i a_i``: least squares over the frames gives
  each cell's area ``a_i`` as the vendor counts it (for Moticon, sensor area
  times its gap factor);
- centre of pressure ``c = sum_i p_i a_i r_i / F``: least squares of
  ``c F`` on ``p`` gives ``a_i r_i``, so the positions ``r_i`` in the
  vendor's own frame.

importers/cell_layouts/moticon-opengo-16.toml holds what

    cd ../shared/realdata/moticon-opengo
    python -m scotti.importers.layout_fit 230927_*.txt
    python -m scotti.importers.layout_fit walk_data_with_events/text_export.txt

print (sizes 7 and 3). A reader with such a column can also fit a file's
own areas (``fit_force_areas``) and render with ``CellLayout.with_areas``.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scotti.importers.errors import InputError

N_PER_CM2_KPA = 10.0  # 1 N/cm^2 = 10 kPa
MIN_FORCE_N = 50.0  # frames with less on the foot say little about the centre of pressure


def fit_force_areas(kpa: np.ndarray, total_n: np.ndarray) -> tuple[np.ndarray, float]:
    """Cell areas (mm^2) with which ``total_n ~ sum(kpa x area)``, and the rms error (N).

    ``kpa`` (N, n) cell pressures, ``total_n`` (N,) the file's total force.
    """
    p = np.asarray(kpa, dtype=np.float64)
    f = np.asarray(total_n, dtype=np.float64)
    coef, *_ = np.linalg.lstsq(p, f, rcond=None)  # N per kPa = 1e-3 m^2
    rms = float(np.sqrt(np.mean((p @ coef - f) ** 2)))
    return coef * 1e3, rms


def fit_positions(
    kpa: np.ndarray, areas_mm2: np.ndarray, cop: np.ndarray, min_force_n: float = MIN_FORCE_N
) -> tuple[np.ndarray, float]:
    """(n, 2) cell positions in the centre-of-pressure frame, and the rms error of the fit.

    ``cop`` (N, 2): the file's centre of pressure per frame.
    """
    p = np.asarray(kpa, dtype=np.float64)
    weight = p * (np.asarray(areas_mm2) * 1e-3)  # (N, n) newtons per cell
    force = weight.sum(axis=1)
    use = force > min_force_n
    moments = np.asarray(cop)[use] * force[use, None]  # (M, 2)
    coef, *_ = np.linalg.lstsq(weight[use], moments, rcond=None)  # (n, 2) = positions
    fitted = weight[use] @ coef / force[use, None]
    rms = float(np.sqrt(np.mean((fitted - np.asarray(cop)[use]) ** 2)))
    return coef, rms


@dataclass(frozen=True)
class SideColumns:
    """One foot's columns of an OpenGo text export."""

    kpa: np.ndarray  # (N, 16)
    total_n: np.ndarray  # (N,)
    cop: np.ndarray  # (N, 2) x, y in [-0.5, 0.5]


def read_opengo_sides(path: Path) -> tuple[int, dict[str, SideColumns]]:
    """The insole size and each foot's pressure, total force and centre of pressure.

    Just what the fit needs; the full reader is importers' vendor readers.
    """
    names: list[str] = []
    size = 0
    with path.open(encoding="utf-8") as f:
        for line in f:
            if not line.startswith("#"):
                break
            text = line[1:].strip()
            if text.startswith("Size:"):
                size = int(text.split(":", 1)[1])
            elif text.startswith("time"):
                names = text.split("\t")
    if not names:
        raise InputError(path, "no '# time ...' column header: not an OpenGo text export")
    data = np.genfromtxt(path, delimiter="\t", comments="#", usecols=range(len(names)))
    sides: dict[str, SideColumns] = {}
    for foot in ("left", "right"):
        cols = [i for i, n in enumerate(names) if n.startswith(f"{foot} pressure ")]
        if len(cols) != 16:
            continue
        total = names.index(f"{foot} total force[N]")
        cop = [i for i, n in enumerate(names) if n.startswith(f"{foot} center of pressure")]
        rows = np.isfinite(data[:, [*cols, total, *cop]]).all(axis=1)
        sides[foot] = SideColumns(
            kpa=data[rows][:, cols] * N_PER_CM2_KPA,
            total_n=data[rows, total],
            cop=data[rows][:, cop],
        )
    return size, sides


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m scotti.importers.layout_fit")
    parser.add_argument(
        "files", nargs="+", type=Path, help="OpenGo text exports of one insole size"
    )
    args = parser.parse_args(argv)
    sizes: set[int] = set()
    parts: list[tuple[str, SideColumns]] = []
    for path in args.files:
        size, sides = read_opengo_sides(path)
        sizes.add(size)
        parts.extend(sides.items())
    if len(sizes) != 1:
        parser.error(f"one insole size at a time, got {sorted(sizes)}")
    size = sizes.pop()
    for foot in ("left", "right"):
        mine = [s for f, s in parts if f == foot]
        kpa = np.concatenate([s.kpa for s in mine])
        total = np.concatenate([s.total_n for s in mine])
        cop = np.concatenate([s.cop for s in mine])
        areas, force_rms = fit_force_areas(kpa, total)
        positions, cop_rms = fit_positions(kpa, areas, cop)
        print(f"# {foot} insole, size {size}: {len(kpa)} frames;")
        print(f"# total force rms {force_rms:.2f} N, centre of pressure rms {cop_rms:.1e} (shares)")
        print("points = [" + ", ".join(f"[{x:.4f}, {y:.4f}]" for x, y in positions) + "]")
        print(f'"{size}" = [' + ", ".join(f"{a:.0f}" for a in areas) + "]")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
