"""kPa per unit of each foot of a vendor recording: from its units, its sensor areas, or a mass.

- Pressure units the file names (kPa, N/cm², mmHg, ...): their factor
  (``recording.KPA_PER_UNIT``), one for every cell.
- Newtons per sensor (gaitpdb): each cell's force over its area, from the
  layout (``importers.layouts``): ``1000 / area_mm2`` kPa per newton.
- Neither (raw sensor values, F-Scan without a calibration, units nobody
  wrote down): the body-mass method, with the wearer's mass (``--mass-kg``):
  over the whole recording the feet held carry, on average, the body's
  weight (both feet) or half of it (one foot). True of walking over whole
  strides and of standing; said in the provenance. Without a mass the
  import stops with a one-line hint.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Final

import numpy as np
from scotti.importers.errors import InputError
from scotti.importers.vendors.recording import FootData, VendorRecording

G: Final = 9.81  # m/s^2


@dataclass(frozen=True)
class FootScale:
    """kPa per unit of one foot's values: a scalar, or one factor per cell."""

    kpa_per_unit: np.ndarray  # () or (n,) float64
    method: str  # "units" | "sensor_area" | "body_mass"

    def describe(self) -> dict[str, Any]:
        factor = self.kpa_per_unit
        shown: Any = float(factor) if factor.ndim == 0 else [round(float(v), 6) for v in factor]
        return {"method": self.method, "kpa_per_unit": shown}


def foot_scales(
    recording: VendorRecording,
    areas_mm2: dict[str, np.ndarray | None],
    mass_kg: float | None,
) -> dict[str, FootScale]:
    """Each foot's factor; ``areas_mm2`` per foot: its cells' or sensels' areas (None: unknown)."""
    out: dict[str, FootScale] = {}
    unknown: list[str] = []
    for foot, data in recording.feet.items():
        if data.kpa_per_unit is not None:
            out[foot] = FootScale(np.asarray(float(data.kpa_per_unit)), "units")
        elif data.units == "N" and areas_mm2.get(foot) is not None:
            area = np.asarray(areas_mm2[foot], dtype=np.float64)
            out[foot] = FootScale(1000.0 / area, "sensor_area")
        else:
            unknown.append(foot)
    if not unknown:
        return out
    if mass_kg is None:
        problem = f"the file gives no usable pressure scale (units {recording.units!r}); "
        problem += "give --mass-kg, the wearer's mass: the mean force over the recording "
        problem += "is then taken as their weight"
        raise InputError(recording.path, problem)
    factor = _from_mass(recording, areas_mm2, mass_kg)
    for foot in unknown:
        out[foot] = FootScale(np.asarray(factor), "body_mass")
    return out


def _from_mass(
    recording: VendorRecording, areas_mm2: dict[str, np.ndarray | None], mass_kg: float
) -> float:
    """kPa per unit that makes the feet held carry their share of ``mass_kg`` on average."""
    unit_m2 = 0.0  # mean over frames of sum(value x area), both feet, in unit x m^2
    for foot, data in recording.feet.items():
        area = areas_mm2.get(foot)
        if area is None:
            problem = f"no sensel area for the {foot} foot: the body-mass scale needs one"
            raise InputError(recording.path, problem)
        unit_m2 += float(_mean_sum(data, np.asarray(area, dtype=np.float64))) * 1e-6
    if unit_m2 <= 0:
        raise InputError(recording.path, "no pressure at all: nothing to scale by the mass")
    share = len(recording.feet) / 2.0
    return mass_kg * G * share / unit_m2 / 1000.0  # Pa per unit -> kPa per unit


def _mean_sum(data: FootData, area_mm2: np.ndarray) -> float:
    values = data.values
    per_frame = values.reshape(values.shape[0], -1).astype(np.float64)
    if data.mask is not None:
        per_frame = per_frame * data.mask.reshape(-1)
    weights = np.broadcast_to(
        area_mm2.reshape(-1) if area_mm2.ndim else area_mm2, per_frame.shape[1:]
    )
    return float((per_frame @ weights).mean())
