"""A vendor recording onto the import's one path (importers/feet.py): each foot's map to counts.

A grid foot: turned into our orientation, remapped by shared area onto
32 x 22 (importers/grid.py, with the file's outline), times its kPa factor,
through our transfer curve. A foot of discrete cells: each cell's value
times its factor (kPa), rendered onto 32 x 22 by its layout
(importers/layouts.py), through our curve. Point sensors (gaitpdb) measure
force at a few points, not pressure over the sole: after rendering, the
foot is scaled so that its force on our grid (pressure x our nominal taxel
area) equals the file's own total for that foot, frame by frame (the total
is averaged onto the output frames with the cells, so the two agree).
"""

from __future__ import annotations

from typing import Any, Final, Protocol

import numpy as np
from scotti.importers.errors import InputError
from scotti.importers.feet import FeetSource, FootMap
from scotti.importers.grid import GridMapper, Orientation
from scotti.importers.vendors.recording import FootData, VendorRecording
from scotti.importers.vendors.scale import FootScale, foot_scales
from scotti.models.input_checks import TAXEL_AREA_M2
from scotti.models.insole import counts_from_kpa

N_PER_KPA: Final = 1e3 * TAXEL_AREA_M2  # one kPa on one of our taxels, in newtons


class _Renderer(Protocol):
    def __call__(self, kpa: np.ndarray) -> np.ndarray: ...


class GridFootMap:
    """(n, rows * cols) source units -> (n, 32, 22) float32 counts."""

    def __init__(
        self,
        shape: tuple[int, int],
        orientation: Orientation,
        mask: np.ndarray | None,
        scale: FootScale,
    ) -> None:
        self.shape, self.orientation = shape, orientation
        oriented = orientation.apply(np.zeros((1, *shape)))[0]
        live = None if mask is None else orientation.apply_mask(mask)
        self.mapper = GridMapper(oriented.shape[0], oriented.shape[1], live)
        self.kpa = np.float32(float(scale.kpa_per_unit))

    def __call__(self, flat: np.ndarray) -> np.ndarray:
        frames = np.asarray(flat, dtype=np.float32).reshape(-1, *self.shape)
        return counts_from_kpa(self.mapper(self.orientation.apply(frames)) * self.kpa)


class CellFootMap:
    """(n, cells [+ 1 total]) source units -> (n, 32, 22) float32 counts."""

    def __init__(self, cells: int, renderer: _Renderer, scale: FootScale, to_total: bool) -> None:
        self.cells, self.renderer, self.to_total = cells, renderer, to_total
        self.kpa = np.asarray(scale.kpa_per_unit, dtype=np.float64)

    def __call__(self, flat: np.ndarray) -> np.ndarray:
        kpa = np.asarray(self.renderer(flat[:, : self.cells] * self.kpa), dtype=np.float64)
        if self.to_total:
            force = kpa.sum(axis=(1, 2)) * N_PER_KPA
            total = flat[:, self.cells]
            ratio = np.divide(total, force, out=np.zeros_like(force), where=force > 1e-9)
            kpa *= ratio[:, None, None]
        return counts_from_kpa(kpa.astype(np.float32))


def feet_from_vendor(
    recording: VendorRecording,
    *,
    mass_kg: float | None = None,
    orientations: dict[str, Orientation] | None = None,
) -> tuple[FeetSource, dict[str, Any]]:
    """The recording's feet as the import's source, and what was done to each (provenance)."""
    layouts: dict[str, Any] = {}
    areas: dict[str, np.ndarray | None] = {}
    for foot, data in recording.feet.items():
        if data.is_grid:
            area = data.sensel_area_mm2
            areas[foot] = None if area is None else np.asarray(area, dtype=np.float64)
        else:
            layouts[foot] = _layout(recording, foot, data)
            areas[foot] = np.asarray(layouts[foot].areas_mm2, dtype=np.float64)
    scales = foot_scales(recording, areas, mass_kg)
    maps: dict[str, FootMap] = {}
    parts: list[np.ndarray] = []
    columns: dict[str, slice] = {}
    described: dict[str, Any] = {}
    start = 0
    for foot in ("left", "right"):
        if foot not in recording.feet:
            continue
        data = recording.feet[foot]
        if data.is_grid:
            orientation = (orientations or {}).get(foot) or data.orientation or Orientation()
            rows, cols = data.frame_shape
            maps[foot] = GridFootMap((rows, cols), orientation, data.mask, scales[foot])
            flat = data.values.reshape(data.values.shape[0], -1)
            described[foot] = _grid_info(data, orientation, scales[foot])
        else:
            from scotti.importers.layouts import CellRenderer

            lay = layouts[foot]
            to_total = bool(lay.point_sensors) and data.total_force_n is not None
            maps[foot] = CellFootMap(
                data.values.shape[1], CellRenderer(lay), scales[foot], to_total
            )
            flat = data.values
            if to_total:
                assert data.total_force_n is not None
                flat = np.column_stack([data.values, data.total_force_n.astype(np.float32)])
            described[foot] = _cell_info(data, scales[foot], to_total, lay.size)
        parts.append(np.asarray(flat, dtype=np.float32))
        columns[foot] = slice(start, start + flat.shape[1])
        start += flat.shape[1]
    values = parts[0] if len(parts) == 1 else np.concatenate(parts, axis=1)
    return FeetSource(recording.path, recording.times_s, values, columns, maps), described


def _layout(recording: VendorRecording, foot: str, data: FootData) -> Any:
    from scotti.importers.layouts import LayoutError, layout

    assert data.layout is not None
    try:
        lay = layout(data.layout, data.layout_size).for_foot(foot)  # type: ignore[arg-type]
    except LayoutError as exc:
        raise InputError(recording.path, str(exc)) from None
    cells = len(np.asarray(lay.areas_mm2))
    if cells != data.values.shape[1]:
        problem = f"{data.values.shape[1]} cells a foot, the layout {data.layout} has {cells}"
        raise InputError(recording.path, problem)
    return lay


def _grid_info(data: FootData, orientation: Orientation, scale: FootScale) -> dict[str, Any]:
    rows, cols = data.frame_shape
    return {
        "grid": [rows, cols],
        "orientation": {
            "toes": "first_row" if orientation.toes_first_row else "last_row",
            "medial": "first_col" if orientation.medial_first_col else "last_col",
            "transpose": orientation.transpose,
        },
        "outline_cells": None if data.mask is None else int(data.mask.sum()),
        "sensel_area_mm2": data.sensel_area_mm2,
        "units": data.units,
        **scale.describe(),
    }


def _cell_info(
    data: FootData, scale: FootScale, to_total: bool, layout_size: str
) -> dict[str, Any]:
    out: dict[str, Any] = {
        "cells": int(data.values.shape[1]),
        "layout": data.layout,
        "layout_size": layout_size,
        "units": data.units,
        **scale.describe(),
        "scaled_to_file_total": to_total,
    }
    if data.total_force_n is not None:
        total = data.total_force_n
        out["file_total_force_n"] = {
            "mean": round(float(total.mean()), 2),
            "max": round(float(total.max()), 2),
        }
    return out
