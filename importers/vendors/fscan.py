"""Tekscan F-Scan ASCII movie (.asf): one insole's grid a file, ``B`` where no sensel is.

    DATA_TYPE MOVIE
    VERSION Tekscan Pressure Measurement System 6.33
    SENSOR_TYPE FSCAN
    ROWS 60
    COLS 21
    ROW_SPACING 5.08 mm
    SENSEL_AREA 25.8064 mm2
    SECONDS_PER_FRAME 0.032
    CALIBRATION_POINT_1 75.0001 (Kgs) 4798 (Raw Sum) 240 (Number of Loaded Cells)
    START_FRAME 1
    END_FRAME 205
    UNITS KPa
    MIRROR_ROW 0
    MIRROR_COL 0
    ASCII_DATA @@

    Frame 1
    B,B,B,0,0,18,...            (ROWS lines of COLS cells)
    ...
    @@

``NAME value`` header lines; frames of ROWS lines of COLS comma-separated
cells, each after a ``Frame N`` line; ``B`` marks a cell outside the
sensor's outline. Frame N is at ``(N - START_FRAME) * SECONDS_PER_FRAME``.

Units: ``UNITS`` names them. Raw sensel values (``UNITS Raw``) are put
into kPa by the header's calibration point: ``m`` kg gave a raw sum of
``S``, so one raw unit on one sensel is ``m g / S / SENSEL_AREA``. Without
either the file has no usable scale (``kpa_per_unit`` None).

The file does not say which foot it is. The grid is stored as seen from
above, toes at row 0 (Tekscan's map view; ``MIRROR_ROW`` / ``MIRROR_COL``
say where the export was flipped), so the foot follows from the sensor's
outline: an insole is cut longer on the big-toe side, so the toe end of the
outline leans to the medial side, the last column for a left insole seen
from above and the first for a right one.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Final

import numpy as np
from scotti.importers.errors import InputError
from scotti.importers.grid import Orientation
from scotti.importers.vendors.lines import Rows, TextLines, file_size, is_gzip
from scotti.importers.vendors.numbers import check_pressures, field_number
from scotti.importers.vendors.recording import FootData, VendorRecording, kpa_per_unit

G: Final = 9.81
MAX_CELLS: Final = 1 << 16  # rows x cols of any insole sensor, with room to spare
_MIN_CELL_BYTES: Final = 2  # "0,"
_FRAME: Final = re.compile(r"^\s*Frame\s+(\d+)\s*$", re.IGNORECASE)
MAX_FRAME_DIGITS: Final = 15  # frame numbers stay exact as float64 time stamps
MAX_PERIOD_S: Final = 60.0  # a frame a minute is already no insole recording
_HEADER: Final = re.compile(r"^\s*([A-Z][A-Z0-9_]*)\s*(.*?)\s*$")
MIN_LEAN_COLS: Final = 0.25  # a toe end leaning less than this says nothing of the foot


def read_fscan(path: Path, foot: str | None = None) -> VendorRecording:
    """``foot``: which insole it is, where the file cannot tell (else from its outline)."""
    fields: dict[str, str] = {}
    comments: list[str] = []
    with TextLines(path) as lines:
        rows = cols = 0
        body: Rows | None = None
        outline: np.ndarray | None = None
        frame_numbers: list[int] = []
        grid: list[np.ndarray] = []
        in_comments = False
        for _, line in lines:
            text = line.strip()
            if body is None:
                if text.startswith("ASCII_DATA"):
                    rows, cols = _size(fields, lines)
                    _check_declared(path, fields, rows, cols, lines)
                    body = Rows(rows * cols)
                    outline = np.ones((rows, cols), dtype=bool)
                    continue
                found = _HEADER.match(line)
                if found and found.group(1) != "COMMENTS" and (found.group(2) or not in_comments):
                    fields[found.group(1)] = found.group(2)
                    in_comments = False
                elif text.startswith("COMMENTS"):
                    in_comments = True
                elif in_comments and text:
                    comments.append(text)
                continue
            if not text:
                continue
            frame = _FRAME.match(text)
            if frame:
                if grid:
                    raise lines.fail(f"frame {frame_numbers[-1]} has {len(grid)} rows, not {rows}")
                if len(frame.group(1)) > MAX_FRAME_DIGITS:
                    raise lines.fail(f"frame number of {len(frame.group(1))} digits")
                frame_numbers.append(int(frame.group(1)))
                continue
            if text == "@@":
                break
            if not frame_numbers:
                raise lines.fail("values before the first 'Frame' line")
            grid.append(_row(text, cols, lines))
            if len(grid) > rows:
                raise lines.fail(f"frame {frame_numbers[-1]} has more than {rows} rows")
            if len(grid) == rows:
                values = np.stack(grid)
                assert outline is not None
                outline &= ~np.isnan(values)
                body.add(np.nan_to_num(values, nan=0.0).reshape(-1))
                grid = []
        if body is None:
            raise InputError(path, "no ASCII_DATA line: not an F-Scan ASCII export")
        if grid:
            raise lines.fail(f"frame {frame_numbers[-1]} ends after {len(grid)} of {rows} rows")
        if not len(body):
            raise InputError(path, "no frames after ASCII_DATA")
        assert outline is not None
        times = _times(path, fields, frame_numbers, lines)
    values = body.array().reshape(-1, rows, cols)
    return _recording(path, times, values, outline, fields, comments, frame_numbers, foot)


def _size(fields: dict[str, str], lines: TextLines) -> tuple[int, int]:
    if "ROWS" not in fields or "COLS" not in fields:
        raise lines.fail("ROWS and COLS must come before ASCII_DATA")
    rows = int(field_number(fields["ROWS"], lines, "ROWS"))
    cols = int(field_number(fields["COLS"], lines, "COLS"))
    if rows <= 0 or cols <= 0 or rows * cols > MAX_CELLS:
        raise lines.fail(f"a sensor of {rows} x {cols} sensels")
    return rows, cols


def _check_declared(
    path: Path, fields: dict[str, str], rows: int, cols: int, lines: TextLines
) -> None:
    if "START_FRAME" not in fields or "END_FRAME" not in fields:
        return
    first = int(field_number(fields["START_FRAME"], lines, "START_FRAME"))
    last = int(field_number(fields["END_FRAME"], lines, "END_FRAME"))
    frames = last - first + 1
    if frames < 1:
        raise lines.fail(f"END_FRAME {last} before START_FRAME {first}")
    if frames * rows * cols * _MIN_CELL_BYTES > file_size(path) and not is_gzip(path):
        problem = f"declares {frames} frames of {rows} x {cols}, more than the file can hold"
        raise InputError(path, problem)


def _row(text: str, cols: int, lines: TextLines) -> np.ndarray:
    cells = text.split(",")
    if len(cells) != cols:
        raise lines.fail(f"{len(cells)} cells, expected {cols} (COLS)")
    out = np.empty(cols)
    for i, cell in enumerate(cells):
        cell = cell.strip()
        if cell == "B":
            out[i] = np.nan
            continue
        try:
            out[i] = float(cell)
        except ValueError:
            raise lines.fail(f"{cell[:20]!r} is neither a number nor B", column=i + 1) from None
    check_pressures(out, lines, allow_nan=True)
    return out


def _times(path: Path, fields: dict[str, str], numbers: list[int], lines: TextLines) -> np.ndarray:
    if "SECONDS_PER_FRAME" not in fields:
        raise InputError(path, "no SECONDS_PER_FRAME: the frame rate is unknown")
    period = field_number(fields["SECONDS_PER_FRAME"], lines, "SECONDS_PER_FRAME")
    if not 0 < period <= MAX_PERIOD_S:
        raise InputError(path, f"SECONDS_PER_FRAME {period:g}")
    frames = np.asarray(numbers, dtype=np.float64)
    steps = np.diff(frames)
    if (steps <= 0).any():
        i = int(np.argmax(steps <= 0)) + 1
        raise InputError(path, f"Frame {numbers[i]} after Frame {numbers[i - 1]}")
    first = float(numbers[0])
    if fields.get("START_FRAME"):
        first = field_number(fields["START_FRAME"], lines, "START_FRAME")
        if abs(first) >= 10.0**MAX_FRAME_DIGITS:
            raise InputError(path, f"START_FRAME {first:g}")
    return (frames - first) * period


def scale(fields: dict[str, str]) -> tuple[str, float | None, dict[str, Any]]:
    """(units, kPa per unit or None, how) from UNITS and the calibration point."""
    units = fields.get("UNITS", "").strip() or "raw"
    known = kpa_per_unit(units)
    calibration = _calibration(fields)
    if known is not None:
        return units, known, {"from": "UNITS", **calibration}
    if {"mass_kg", "raw_sum"} <= calibration.keys() and "SENSEL_AREA" in fields:
        area_mm2 = _first_number(fields["SENSEL_AREA"])
        if area_mm2 and calibration["raw_sum"] > 0:
            newtons_per_raw = calibration["mass_kg"] * G / calibration["raw_sum"]
            kpa = newtons_per_raw / (area_mm2 * 1e-6) / 1000.0
            return units, kpa, {"from": "CALIBRATION_POINT_1", **calibration}
    return units, None, {"from": None, **calibration}


def _calibration(fields: dict[str, str]) -> dict[str, Any]:
    text = fields.get("CALIBRATION_POINT_1", "")
    found = re.match(r"\s*([\d.]+)\s*\(Kgs?\)\s*([\d.]+)\s*\(Raw Sum\)", text, re.IGNORECASE)
    if not found:
        return {}
    return {"mass_kg": float(found.group(1)), "raw_sum": float(found.group(2))}


def _first_number(text: str) -> float | None:
    found = re.search(r"[-+]?\d*\.?\d+(?:[eE][-+]?\d+)?", text)
    return float(found.group(0)) if found else None


def foot_from_outline(outline: np.ndarray) -> tuple[str | None, float]:
    """("left" | "right" | None, lean) from a grid seen from above, toes at row 0.

    ``lean`` is how far the centre of the outline's toe end (its first tenth
    of live rows) lies from the centre of the whole outline, in columns:
    positive toward the last column, the big-toe side of a left insole.
    None where the toe end does not lean by a quarter of a column: a
    symmetric outline says nothing.
    """
    live_rows = np.flatnonzero(outline.any(axis=1))
    cols = np.arange(outline.shape[1], dtype=np.float64)
    whole = float((outline * cols).sum() / max(outline.sum(), 1))
    toe_rows = live_rows[: max(1, live_rows.size // 10)]
    toe = outline[toe_rows]
    toe_centre = float((toe * cols).sum() / max(toe.sum(), 1))
    lean = toe_centre - whole
    if abs(lean) < MIN_LEAN_COLS:
        return None, lean
    return ("left" if lean > 0 else "right"), lean


def foot_from_name(*names: str) -> str | None:
    """A name's last letter L or R (``FrasP01L``, ``walk_r``), or a final left / right."""
    for name in names:
        stem = re.split(r"[\\/]", name.strip())[-1].rsplit(".", 1)[0]
        lowered = stem.lower()
        for side in ("left", "right"):
            letter = side[0].upper()
            if lowered.endswith(side):
                return side
            lone = len(stem) <= 1 or not stem[-2].isalpha() or stem[-2].islower()
            if stem.endswith(letter) and lone:  # capital after a digit or lower case
                return side
            if re.search(rf"[^a-z0-9]{letter.lower()}$", lowered):  # walk_r, walk-l
                return side
    return None


def _recording(
    path: Path,
    times: np.ndarray,
    values: np.ndarray,
    outline: np.ndarray,
    fields: dict[str, str],
    comments: list[str],
    numbers: list[int],
    given: str | None,
) -> VendorRecording:
    mirror_rows = _first_number(fields.get("MIRROR_ROW", "0")) == 1
    mirror_cols = _first_number(fields.get("MIRROR_COL", "0")) == 1
    seen_from_above = outline[::-1] if mirror_rows else outline
    seen_from_above = seen_from_above[:, ::-1] if mirror_cols else seen_from_above
    found, lean = foot_from_outline(seen_from_above)
    named = foot_from_name(path.name, fields.get("FILENAME", ""))
    foot = given or found or named
    if foot is None:
        problem = "which foot? the sensor's outline is symmetric and the file's name ends "
        problem += "in neither L nor R: --foot left or right"
        raise InputError(path, problem)
    side_from = "given" if given else ("outline" if found else "file name")
    medial_last = (foot == "left") != mirror_cols
    orientation = Orientation(toes_first_row=not mirror_rows, medial_first_col=not medial_last)
    units, kpa, calibration = scale(fields)
    area = _first_number(fields.get("SENSEL_AREA", ""))
    data = FootData(
        values,
        units,
        kpa,
        orientation=orientation,
        mask=outline,
        sensel_area_mm2=area,
    )
    rate = 1.0 / float(_first_number(fields["SECONDS_PER_FRAME"]) or 1.0)
    info: dict[str, Any] = {
        "fields": fields,
        "comments": comments,
        "sensor_type": fields.get("SENSOR_TYPE", ""),
        "frame_numbers": [numbers[0], numbers[-1]],
        "foot": {
            "side": foot,
            "from": side_from,
            "toe_lean_cols": round(lean, 2),
            "name_says": named,
        },
        "calibration": calibration,
        "outline_cells": int(outline.sum()),
        "outline": ["".join("1" if v else "0" for v in row) for row in outline],  # 0: a B
    }
    return VendorRecording("fscan", path, times, {foot: data}, rate, units, [], info)
