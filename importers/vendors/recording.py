"""What every vendor reader returns: one recording, its feet, its clock and what else it said.

A foot is either a dense grid (N, rows, cols) with how it lies
(``importers.grid.Orientation``) or discrete cells (N, n) with the name of
their layout (``importers.layouts``). Values stay in the file's own units;
``kpa_per_unit`` says how to get kPa (None: the file gives no usable scale,
and the import falls back to the body-mass method or refuses). A foot the
file does not hold is not in ``feet``: a one-foot recording.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final, Literal

import numpy as np
from scotti.importers.grid import Orientation

FOOT_NAMES: Final = ("left", "right")
FootName = Literal["left", "right"]

# kPa per unit of the units the vendors write (their own spelling, lower-cased).
KPA_PER_UNIT: Final[dict[str, float]] = {
    "kpa": 1.0,
    "n/cm²": 10.0,  # 1 N/cm² = 10^4 Pa
    "n/cm2": 10.0,
    "mmhg": 0.133322,  # 133.322 Pa
    "psi": 6.894757,
    "mpa": 1000.0,
    "pa": 0.001,
}


def kpa_per_unit(units: str) -> float | None:
    """kPa per unit of ``units`` as a file spells it, None when unknown."""
    return KPA_PER_UNIT.get(units.strip().lower())


@dataclass(frozen=True, eq=False)
class FootData:
    """One foot as the file stores it."""

    values: np.ndarray  # (N, rows, cols) grid or (N, n) cells, float32 >= 0, file units
    units: str  # as the file names them: "kPa", "N/cm²", "mmHg", "N" (force per sensor), "raw"
    kpa_per_unit: float | None  # None: per-sensor newtons (layout areas) or no usable scale
    orientation: Orientation | None = None  # grids: how the grid lies (None for cells)
    layout: str | None = None  # cells: the layout's name in importers.layouts
    layout_size: str | None = None  # cells: the vendor's insole size, as the file names it
    mask: np.ndarray | None = None  # bool, (rows, cols) or (n,): True where a taxel/cell is live
    sensel_area_mm2: float | None = None  # grids: one taxel's area, when the file says it
    total_force_n: np.ndarray | None = None  # (N,) the file's own total force of this foot

    @property
    def is_grid(self) -> bool:
        return self.values.ndim == 3

    @property
    def frame_shape(self) -> tuple[int, ...]:
        return tuple(int(s) for s in self.values.shape[1:])


@dataclass(frozen=True, eq=False)
class VendorRecording:
    """A vendor file read whole: times, the feet it holds, rate, units, events, the rest."""

    format: str  # the reader's name (importers.vendors.FORMATS)
    path: Path
    times_s: np.ndarray  # (N,) float64 seconds on the file's own clock, strictly increasing
    feet: dict[str, FootData]  # "left"/"right" -> the foot; a foot not held is absent
    rate_hz: float  # the rate the file declares (or its time stamps show)
    units: str  # the pressure units the file states
    events: list[tuple[float, str]] = field(default_factory=list)  # (time_s, name), file clock
    info: dict[str, Any] = field(default_factory=dict)  # JSON-able: header fields, tags, sensor

    @property
    def absent_feet(self) -> list[str]:
        return [f for f in FOOT_NAMES if f not in self.feet]
