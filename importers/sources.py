"""Which reader a pressure file takes, and what the run gets from it: a table or a vendor's export.

``load_pressure(cfg)`` picks the format (``pressure.format``; ``auto``: the
file's own header, importers/vendors/detect.py), reads the file and hands
the run the feet it holds on the import's one path (importers/feet.py),
with what the session's header should say about it (its provenance), the
thinned source frames for pictures, and what the file knows of the wearer
and the wall clock.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scotti.firmware_protocol.session import SourceFrameRecord
from scotti.importers.config import FootGrid, ImportConfig
from scotti.importers.errors import InputError
from scotti.importers.feet import FEET, FeetSource
from scotti.importers.grid import Orientation
from scotti.importers.pressure import CountMapper, feet_from_table, read_pressure
from scotti.importers.vendors import VendorRecording, detect, read_vendor
from scotti.importers.vendors.to_feet import feet_from_vendor


@dataclass(frozen=True, eq=False)
class LoadedPressure:
    """A pressure file read, ready for the run."""

    feet: FeetSource
    format: str  # "table" or a vendor format's name
    provenance: dict[str, Any]  # the header's "pressure" (and "vendor", "events") entries
    counts: dict[str, Any]  # the header's "counts" entry: how values became counts
    source_frames: list[SourceFrameRecord] = field(default_factory=list)
    start_unix: float | None = None  # the file's own wall clock at its first frame
    subject: dict[str, Any] = field(default_factory=dict)  # what the file says of the wearer


def pressure_format(cfg: ImportConfig) -> str:
    chosen = cfg.pressure.format
    return detect(cfg.path(cfg.pressure.file)) if chosen == "auto" else chosen


def load_pressure(cfg: ImportConfig) -> LoadedPressure:
    name = pressure_format(cfg)
    if name == "table":
        return _table(cfg)
    _check_vendor_config(cfg, name)
    recording = read_vendor(cfg.path(cfg.pressure.file), name, foot=cfg.pressure.foot)
    return _vendor(cfg, recording)


def _table(cfg: ImportConfig) -> LoadedPressure:
    source = read_pressure(cfg)
    mapper = CountMapper(cfg, source)
    p = cfg.pressure
    provenance = {
        "file": source.path.name,
        "format": "table",
        "rows": p.rows,
        "cols": p.cols,
        "frames": int(source.times.size),
        "rate_hz": source.rate_hz,
        "first_s": float(source.times[0]),
        "last_s": float(source.times[-1]),
        "left": p.left.model_dump(),
        "right": p.right.model_dump(),
    }
    counts = {
        "method": cfg.counts.method,
        "gain": cfg.counts.gain,
        "kpa_per_unit": mapper.kpa_per_unit,
    }
    frames = _thinned(source.times, source.frames, cfg.source_every_s)
    return LoadedPressure(
        feet_from_table(source, mapper), "table", {"pressure": provenance}, counts, frames
    )


def _check_vendor_config(cfg: ImportConfig, name: str) -> None:
    """Keys that are for tables only, given for a vendor file: a mistake to name, not ignore."""
    p = cfg.pressure
    where = cfg.path(p.file)
    table_only = {"rows", "cols", "time_unit", "time_column", "first_column", "feet"}
    table_only |= {"taxel_order", "time_key", "left_key", "right_key", "frames_key"}
    table_only |= {"right_time_key"}
    given = sorted(table_only & p.model_fields_set)
    if given:
        shown = ", ".join(f"pressure.{k}" for k in given)
        raise InputError(where, f"{shown}: for tables only; a {name} file says its own")
    if "counts" in cfg.model_fields_set:
        problem = f"[counts] is for tables; a {name} file states its units "
        problem += "(--mass-kg scales one that does not)"
        raise InputError(where, problem)


def _orientation_overrides(cfg: ImportConfig) -> dict[str, Orientation]:
    out: dict[str, Orientation] = {}
    for foot in FEET:
        if foot in cfg.pressure.model_fields_set:
            g: FootGrid = getattr(cfg.pressure, foot)
            out[foot] = Orientation(g.toes == "first_row", g.medial == "first_col", g.transpose)
    return out


def _vendor(cfg: ImportConfig, recording: VendorRecording) -> LoadedPressure:
    feet, described = feet_from_vendor(
        recording, mass_kg=cfg.mass_kg, orientations=_orientation_overrides(cfg)
    )
    times = recording.times_s
    provenance = {
        "file": recording.path.name,
        "format": recording.format,
        "frames": int(times.size),
        "rate_hz": recording.rate_hz,
        "measured_rate_hz": feet.rate_hz,
        "first_s": float(times[0]),
        "last_s": float(times[-1]),
        "units": recording.units,
        "sensor_type": recording.info.get("sensor_type", ""),
        "feet": described,
        "absent_feet": list(feet.absent),
    }
    header = {
        "pressure": provenance,
        "vendor": _jsonable(recording.info),
        "events": [[round(t, 6), name] for t, name in recording.events],
    }
    methods = sorted({d["method"] for d in described.values()})
    counts: dict[str, Any] = {"method": "+".join(methods), "from": "the file's units"}
    if "body_mass" in methods:
        counts |= {"mass_kg": cfg.mass_kg, "assumes": "mean force over the recording = weight"}
    start = recording.info.get("start_unix")
    return LoadedPressure(
        feet,
        recording.format,
        header,
        counts,
        _vendor_frames(recording, cfg.source_every_s),
        float(start) if isinstance(start, int | float) else None,
        _wearer(recording),
    )


def _vendor_frames(recording: VendorRecording, every_s: float) -> list[SourceFrameRecord]:
    """Grids only, both feet side by side as stored (NaN for a foot not held)."""
    grids = {f: d.values for f, d in recording.feet.items() if d.is_grid}
    shapes = {v.shape[1:] for v in grids.values()}
    if not grids or len(grids) != len(recording.feet) or len(shapes) != 1:
        return []
    (rows, cols), n = shapes.pop(), recording.times_s.size
    both = np.full((n, 2, rows, cols), np.nan, dtype=np.float32)
    for foot, values in grids.items():
        both[:, FEET.index(foot)] = values
    return _thinned(recording.times_s, both, every_s)


def _thinned(times: np.ndarray, frames: np.ndarray, every_s: float) -> list[SourceFrameRecord]:
    """One source frame per ``every_s`` seconds (the first of each interval)."""
    if every_s <= 0:
        return []
    bucket = np.floor((times - times[0]) / every_s)
    keep = np.flatnonzero(np.r_[True, bucket[1:] != bucket[:-1]])
    return [SourceFrameRecord(round(float(times[i]) * 1e9), frames[i]) for i in keep.tolist()]


def _wearer(recording: VendorRecording) -> dict[str, Any]:
    """Mass and height where the file (gaitpdb's demographics beside it) says them."""
    row = recording.info.get("demographics") or {}
    out: dict[str, Any] = {}
    mass = _number(row.get("Weight"))
    if mass is not None and 10 <= mass <= 300:
        out["mass_kg"] = mass
    height = _number(row.get("Height"))
    if height is not None:
        height = height / 100.0 if height > 3.0 else height  # some rows are in cm
        if 0.5 <= height <= 2.5:
            out["height_m"] = height
    return out


def _number(text: Any) -> float | None:
    try:
        value = float(text)
    except (TypeError, ValueError):
        return None
    return value if np.isfinite(value) else None


def _jsonable(value: Any) -> Any:
    """``info`` as plain types for the msgpack header (numpy scalars and arrays to lists)."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    return value
