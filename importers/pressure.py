"""Pressure tables (CSV, ``.npz``, HDF5): read, check, and each foot's map onto our counts.

A table holds both feet as grids of the size the configuration names. The
import's path from here is importers/feet.py's: time, then space, then
scale. Resampling in time and remapping in space are both linear, so they
act on the source's own values; the count scale (models/insole.py) may be
a curve, so it comes last, on our grid. Vendor files come in through
importers/vendors/ onto the same path.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np
from scotti.importers.config import TIME_UNITS, CountsConfig, FootGrid, ImportConfig
from scotti.importers.errors import InputError
from scotti.importers.feet import FEET, FeetSource, FootMap
from scotti.importers.grid import GridMapper, Orientation
from scotti.importers.tables import describe_value, first_bad, load_arrays, read_csv
from scotti.models.contract import FRAME_COLS, FRAME_ROWS, MAX_COUNT
from scotti.models.insole import counts_from_kpa

G: Final = 9.81  # m/s^2


@dataclass(frozen=True)
class PressureSource:
    """A pressure recording as stored: both feet, the source's units and grid."""

    path: Path
    times: np.ndarray  # (N,) float64 seconds, strictly increasing
    frames: np.ndarray  # (N, 2, rows, cols) float32 >= 0, left then right, as stored

    @property
    def rate_hz(self) -> float:
        span = float(self.times[-1] - self.times[0]) if self.times.size > 1 else 0.0
        return (self.times.size - 1) / span if span > 0 else 0.0


def table_grid(cfg: ImportConfig) -> tuple[int, int]:
    """A table's grid of one foot (rows, cols): the configuration must say it."""
    p = cfg.pressure
    if p.rows is None or p.cols is None:
        problem = "a pressure table needs its grid: pressure.rows and pressure.cols "
        problem += "(--grid ROWSxCOLS)"
        raise InputError(cfg.path(p.file), problem)
    return p.rows, p.cols


def read_pressure(cfg: ImportConfig) -> PressureSource:
    p = cfg.pressure
    path = cfg.path(p.file)
    if path.suffix.lower() == ".csv":
        times, frames = _from_csv(path, cfg)
    else:
        times, frames = _from_arrays(path, cfg)
    return PressureSource(path, times, frames)


def _from_csv(path: Path, cfg: ImportConfig) -> tuple[np.ndarray, np.ndarray]:
    p = cfg.pressure
    rows, cols = table_grid(cfg)
    taxels = rows * cols
    # Every line as wide as the header (or the first line); float32 as the frames are kept,
    # the time stamps whole.
    table = read_csv(path, narrow=True, wide=(p.time_column,))
    time_col = table.column_of(p.time_column)
    first = p.first_column if p.first_column is not None else time_col + 1
    if first <= time_col < first + 2 * taxels:
        raise InputError(path, f"the time column {time_col} lies among the taxel columns")
    width = max(time_col + 1, first + 2 * taxels)
    if table.values.shape[1] != width:
        problem = f"{table.values.shape[1]} columns, expected {width}"
        problem += f" (time + 2 feet x {rows} x {cols} taxels)"
        line = table.header_line if table.header_line is not None else int(table.lines[0])
        raise InputError(path, problem, line=line)
    times = table.wide[time_col] * TIME_UNITS[p.time_unit]
    _check_times(times, lambda i, problem: table.fail(i, time_col, problem))
    block = table.values[:, first : first + 2 * taxels]
    bad = first_bad(block)
    if bad is not None:
        raise table.fail(bad[0], first + bad[1], describe_value(float(block[bad])))
    if list(p.feet) == list(FEET) and p.taxel_order == "row_major":
        return times, block.reshape(-1, 2, rows, cols)  # a view of the table: no copy
    feet = block.reshape(-1, 2, taxels)
    frames = np.empty((len(times), 2, rows, cols), dtype=np.float32)
    for k, foot in enumerate(p.feet):
        frames[:, FEET.index(foot)] = _unflatten(feet[:, k], rows, cols, p.taxel_order)
    return times, frames


def _unflatten(values: np.ndarray, rows: int, cols: int, order: str) -> np.ndarray:
    if order == "row_major":
        return values.reshape(-1, rows, cols)
    return np.swapaxes(values.reshape(-1, cols, rows), 1, 2)


def _from_arrays(path: Path, cfg: ImportConfig) -> tuple[np.ndarray, np.ndarray]:
    p = cfg.pressure
    rows, cols = table_grid(cfg)
    keys = [p.time_key] + ([p.frames_key] if p.frames_key else [p.left_key, p.right_key])
    if p.right_time_key is not None:
        keys.append(p.right_time_key)
    arrays = load_arrays(path, keys)
    times = _times(path, arrays, p.time_key, TIME_UNITS[p.time_unit])
    own = {"left": times, "right": times}
    if p.right_time_key is not None:
        own["right"] = _times(path, arrays, p.right_time_key, TIME_UNITS[p.time_unit])
    n = times.size
    frames = np.empty((n, 2, rows, cols), dtype=np.float32)
    if p.frames_key:
        both = np.asarray(arrays[p.frames_key])
        if both.shape[:2] != (n, 2):
            problem = f"{p.frames_key} has shape {both.shape}, expected ({n}, 2, {rows}, {cols})"
            raise InputError(path, problem)
        parts = {foot: (f"{p.frames_key}[:, {k}]", both[:, k]) for k, foot in enumerate(p.feet)}
    else:
        parts = {
            "left": (p.left_key, np.asarray(arrays[p.left_key])),
            "right": (p.right_key, np.asarray(arrays[p.right_key])),
        }
    for foot, (name, values) in parts.items():
        count = own[foot].size
        if values.ndim == 2 and values.shape == (count, rows * cols):
            values = _unflatten(values, rows, cols, p.taxel_order)
        if values.shape != (count, rows, cols):
            problem = f"{name} has shape {values.shape}; declared {count} frames of "
            problem += f"{rows} x {cols}"
            raise InputError(path, problem)
        if values.dtype.kind not in "fiu":
            raise InputError(path, f"{name} holds {values.dtype}, not numbers")
        bad = first_bad(values)
        if bad is not None:
            index = ", ".join(map(str, bad))
            raise InputError(path, describe_value(float(values[bad])), column=f"{name}[{index}]")
        if own[foot] is not times:
            values = _onto(own[foot], values, times)
        frames[:, FEET.index(foot)] = values
    return times, frames


def _times(path: Path, arrays: dict[str, np.ndarray], key: str, unit: float) -> np.ndarray:
    stored = np.asarray(arrays[key])
    if stored.dtype.kind not in "fiu":
        raise InputError(path, f"{key} holds {stored.dtype}, not numbers")
    times = stored.astype(np.float64).reshape(-1) * unit

    def at(i: int, problem: str) -> InputError:
        return InputError(path, problem, column=f"{key}[{i}]")

    _check_times(times, at)
    return times


def _onto(t_from: np.ndarray, values: np.ndarray, t_to: np.ndarray) -> np.ndarray:
    """Frames (n, rows, cols) sampled at ``t_from``, linearly interpolated at ``t_to``
    (the first and last frames held beyond the ends)."""
    if t_from.size == 1:
        return np.repeat(values[:1], t_to.size, axis=0)
    i = np.clip(np.searchsorted(t_from, t_to, side="right") - 1, 0, t_from.size - 2)
    w = np.clip((t_to - t_from[i]) / (t_from[i + 1] - t_from[i]), 0.0, 1.0)[:, None, None]
    return np.asarray((1.0 - w) * values[i] + w * values[i + 1])


def _check_times(times: np.ndarray, fail: Callable[[int, str], InputError]) -> None:
    if times.size == 0:
        raise fail(0, "no frames")
    bad = np.flatnonzero(~np.isfinite(times))
    if bad.size:
        raise fail(int(bad[0]), "time stamp is not a number")
    steps = np.diff(times)
    back = np.flatnonzero(steps <= 0)
    if back.size:
        i = int(back[0]) + 1
        kind = "duplicate" if steps[i - 1] == 0 else "earlier than the one before"
        raise fail(i, f"time stamp {kind} ({times[i]:.9g} s after {times[i - 1]:.9g} s)")


# --- onto the contract ------------------------------------------------------


def orientations(cfg: ImportConfig) -> tuple[Orientation, Orientation]:
    def one(g: FootGrid) -> Orientation:
        return Orientation(g.toes == "first_row", g.medial == "first_col", g.transpose)

    return one(cfg.pressure.left), one(cfg.pressure.right)


def source_masks(cfg: ImportConfig) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Each foot's outline (rows, cols) as stored, None when every taxel is live."""
    p = cfg.pressure
    rows, cols = table_grid(cfg)
    out: list[np.ndarray | None] = []
    for grid in (p.left, p.right):
        if grid.outline is None:
            out.append(None)
            continue
        path = cfg.path(grid.outline)
        try:
            mask = np.load(path) if path.suffix == ".npy" else read_csv(path).values
        except (OSError, ValueError) as exc:
            raise InputError(path, f"cannot read the outline ({exc.__class__.__name__})") from None
        if mask.shape != (rows, cols):
            shape = " x ".join(map(str, mask.shape))
            problem = f"outline is {shape}, the grid {rows} x {cols}"
            raise InputError(path, problem)
        out.append(np.asarray(mask) > 0)
    return out[0], out[1]


class CountMapper:
    """Source frames (N, 2, rows, cols) -> our counts (N, 2, 32, 22) uint16."""

    def __init__(self, cfg: ImportConfig, source: PressureSource) -> None:
        rows, cols = table_grid(cfg)
        self.orient = orientations(cfg)
        masks = source_masks(cfg)
        self.source_masks = masks
        self.mappers = []
        for o, m in zip(self.orient, masks, strict=True):
            oriented = o.apply(np.zeros((1, rows, cols)))[0]
            mask = None if m is None else o.apply_mask(m)
            self.mappers.append(GridMapper(oriented.shape[0], oriented.shape[1], mask))
        self.counts = cfg.counts
        self.kpa_per_unit = _kpa_per_unit(cfg, source, masks)

    def on_grid(self, frames: np.ndarray) -> np.ndarray:
        """(N, 2, rows, cols) source units -> (N, 2, 32, 22) float32 source units."""
        out = np.empty((frames.shape[0], 2, FRAME_ROWS, FRAME_COLS), dtype=np.float32)
        for foot in range(2):
            out[:, foot] = self.foot_on_grid(foot, frames[:, foot])
        return out

    def foot_on_grid(self, foot: int, frames: np.ndarray) -> np.ndarray:
        """One foot's (N, rows, cols) source units -> (N, 32, 22) float32 source units."""
        return np.asarray(self.mappers[foot](self.orient[foot].apply(frames)))

    def foot_map(self, foot: int, rows: int, cols: int) -> FootMap:
        """The foot's map for importers/feet.py: (n, rows * cols) -> (n, 32, 22) counts."""

        def counts(flat: np.ndarray) -> np.ndarray:
            return self.to_counts(self.foot_on_grid(foot, flat.reshape(-1, rows, cols)))

        return counts

    def to_counts(self, on_grid: np.ndarray) -> np.ndarray:
        """Source units on our grid -> counts (float32, unrounded)."""
        if self.kpa_per_unit is None:
            return np.minimum(on_grid * np.float32(self.counts.gain), np.float32(MAX_COUNT))
        return counts_from_kpa(on_grid * np.float32(self.kpa_per_unit))

    def __call__(self, frames: np.ndarray) -> np.ndarray:
        counts = self.to_counts(self.on_grid(frames))
        return np.asarray(np.clip(np.rint(counts), 0, MAX_COUNT), dtype=np.uint16)


def _kpa_per_unit(
    cfg: ImportConfig, source: PressureSource, masks: tuple[np.ndarray | None, np.ndarray | None]
) -> float | None:
    c: CountsConfig = cfg.counts
    if c.method == "counts":
        return None
    if c.method == "per_kpa":
        assert c.units_per_kpa is not None  # the config's validator
        return 1.0 / c.units_per_kpa
    assert c.mass_kg is not None
    assert c.stand_s is not None
    assert c.taxel_area_mm2 is not None
    t = source.times - source.times[0]
    stand = (t >= c.stand_s[0]) & (t <= c.stand_s[1])
    if not stand.any():
        problem = f"counts.stand_s {list(c.stand_s)} holds no frame (the recording is "
        problem += f"{t[-1]:.2f} s long)"
        raise InputError(cfg.path(cfg.pressure.file), problem)
    live = [np.ones(source.frames.shape[2:]) if m is None else m for m in masks]
    units = sum((source.frames[stand, k] * live[k]).sum(axis=(1, 2)) for k in range(2))
    mean_units = float(np.mean(units)) * c.taxel_area_mm2 * 1e-6  # unit * m^2
    if mean_units <= 0:
        raise InputError(cfg.path(cfg.pressure.file), "no pressure at all in counts.stand_s")
    return c.mass_kg * G / mean_units / 1000.0  # Pa per unit -> kPa per unit


def feet_from_table(source: PressureSource, mapper: CountMapper) -> FeetSource:
    """A table's two feet as the import's source: its frames, flat, and each foot's map."""
    n, _, rows, cols = source.frames.shape
    taxels = rows * cols
    return FeetSource(
        path=source.path,
        times=source.times,
        values=source.frames.reshape(n, 2 * taxels),  # a view: left's taxels, then right's
        columns={"left": slice(0, taxels), "right": slice(taxels, 2 * taxels)},
        maps={foot: mapper.foot_map(k, rows, cols) for k, foot in enumerate(FEET)},
    )
