"""XSENSOR X4 foot CSV export: per frame, a block per insole sensor, pressures in a grid.

    File:,"C:\\...\\walk.XSN"
    Units:,mmHg
    Threshold:,51.72
    FRAME,1464
    Date, 2022 Aug 16
    Time, 08:21:17.982
    SENSOR,HX210.11.31.M11-DFM-LF S0073       (LF: left foot, RF: right foot)
    Rows,31
    Columns,11
    Sensel Width (cm),0.86
    Sensel Height (cm),0.86
    Est. Load (N),411.67                      (and more statistics of the frame)
    SENSELS
    0,0,0,0,0,107.87,0,0,174.74,89.9,0,,,,    (Rows lines of Columns values)
    SENSOR,HX210.11.31.M11-DFM-RF S0073
    ...
    GROUP,1                                   (regions: statistics and their cells; skipped)
    ...
    FRAME,1465

Blank lines (only commas) come between all of these. A frame's time is
its Date and Time (to the millisecond); the recording's clock starts at
the first frame. A sensor whose name ends in ``LF`` / ``RF`` is that foot;
a file with one of them is a one-foot recording. The grid is stored as
seen from above with the toes at row 0 (XSENSOR's foot view): the big toe
at the last column of a left insole and the first of a right one.
"""

from __future__ import annotations

import csv
import re
from datetime import datetime
from pathlib import Path
from typing import Any, Final

import numpy as np
from scotti.importers.errors import InputError, clip
from scotti.importers.grid import Orientation
from scotti.importers.vendors.lines import Rows, TextLines
from scotti.importers.vendors.numbers import (
    Clock,
    check_pressures,
    check_readings,
    field_number,
    numbers,
)
from scotti.importers.vendors.recording import FootData, VendorRecording, kpa_per_unit

MAX_CELLS: Final = 1 << 16
_SIDES: Final = {"LF": "left", "RF": "right"}
_LOAD: Final = "Est. Load (N)"
_SIDE: Final = re.compile(r"-(LF|RF)\b", re.IGNORECASE)


class _Sensor:
    """One foot's frames, as they come."""

    def __init__(self, name: str, rows: int, cols: int, area_mm2: float | None) -> None:
        self.name, self.rows, self.cols, self.area_mm2 = name, rows, cols, area_mm2
        self.values = Rows(rows * cols)
        self.load = Rows(1)


def read_xsensor(path: Path) -> VendorRecording:
    top: dict[str, str] = {}
    sensors: dict[str, _Sensor] = {}
    stamps: list[datetime] = []
    frame_numbers: list[int] = []
    with TextLines(path) as lines:
        foot: str | None = None  # the sensor block being read (None: between blocks, in groups)
        fields: dict[str, str] = {}
        grid: list[np.ndarray] | None = None
        date = ""
        clock = Clock()
        for _, line in lines:
            cells = _cells(line, lines)
            if not any(c.strip() for c in cells):
                continue
            key = cells[0].strip()
            if grid is not None:  # inside a sensor's SENSELS
                sensor = sensors[foot] if foot else None
                assert sensor is not None
                grid.append(_row(cells, sensor.cols, lines))
                if len(grid) == sensor.rows:
                    _finish(sensor, grid, fields, lines)
                    grid, foot = None, None
                continue
            if key == "FRAME":
                _close_frame(sensors, frame_numbers, lines)
                frame_numbers.append(int(field_number(_value(cells), lines, "FRAME")))
                foot, fields, date = None, {}, ""
            elif not frame_numbers:
                top[key.rstrip(":")] = _value(cells)
            elif key == "Date":
                date = _value(cells)
            elif key == "Time":
                stamps.append(_stamp(date, _value(cells), lines))
                clock.check((stamps[-1] - stamps[0]).total_seconds(), lines, 2)
            elif key == "SENSOR":
                foot, fields = _sensor_foot(_value(cells), lines), {}
                if foot in sensors and len(sensors[foot].load) >= len(frame_numbers):
                    raise lines.fail(f"a second {foot} sensor in frame {frame_numbers[-1]}")
                fields["SENSOR"] = _value(cells)
            elif key == "GROUP":
                foot = None
            elif key == "SENSELS" and foot is not None:
                sensor = _sensor(sensors, foot, fields, lines)
                grid = []
            elif foot is not None:
                fields[key] = _value(cells)
                if key == _LOAD:  # checked on its own line, kept as a number at the grid's end
                    _load(fields[key], lines)
        if grid is not None:
            raise lines.fail("the file ends inside a SENSELS block")
        _close_frame(sensors, frame_numbers, lines)
        if not frame_numbers or not sensors:
            raise InputError(path, "no FRAME with a SENSOR block: not an XSENSOR export")
        if len(stamps) != len(frame_numbers):
            raise InputError(path, f"{len(stamps)} Time lines for {len(frame_numbers)} frames")
    return _recording(path, top, sensors, stamps, frame_numbers)


def _cells(line: str, lines: TextLines) -> list[str]:
    if not line:
        return []
    try:
        return next(csv.reader([line]))
    except csv.Error as exc:  # a carriage return or quote where CSV allows none
        raise lines.fail(f"not a CSV line ({clip(str(exc), 60)})") from None


def _value(cells: list[str]) -> str:
    return cells[1].strip() if len(cells) > 1 else ""


def _stamp(date: str, clock: str, lines: TextLines) -> datetime:
    for form in ("%Y %b %d %H:%M:%S.%f", "%Y %b %d %H:%M:%S"):
        try:
            return datetime.strptime(f"{date} {clock}".strip(), form)
        except ValueError:
            continue
    raise lines.fail(f"time stamp {date!r} {clock!r} is not 'YYYY Mon DD HH:MM:SS.mmm'")


def _sensor_foot(name: str, lines: TextLines) -> str:
    found = _SIDE.search(name)
    if not found:
        raise lines.fail(f"sensor {name!r}: its name ends in neither LF nor RF (which foot?)")
    return _SIDES[found.group(1).upper()]


def _sensor(
    sensors: dict[str, _Sensor], foot: str, fields: dict[str, str], lines: TextLines
) -> _Sensor:
    rows = int(field_number(fields.get("Rows", ""), lines, "Rows"))
    cols = int(field_number(fields.get("Columns", ""), lines, "Columns"))
    if rows <= 0 or cols <= 0 or rows * cols > MAX_CELLS:
        raise lines.fail(f"a sensor of {rows} x {cols} sensels")
    sensor = sensors.get(foot)
    if sensor is None:
        area = _area_mm2(fields)
        sensor = sensors[foot] = _Sensor(fields.get("SENSOR", ""), rows, cols, area)
    elif (sensor.rows, sensor.cols) != (rows, cols):
        shape = f"{rows} x {cols}, earlier {sensor.rows} x {sensor.cols}"
        raise lines.fail(f"the {foot} sensor changes its grid: {shape}")
    return sensor


def _area_mm2(fields: dict[str, str]) -> float | None:
    try:
        width = float(fields["Sensel Width (cm)"])
        height = float(fields["Sensel Height (cm)"])
    except (KeyError, ValueError):
        return None
    return width * height * 100.0


def _row(cells: list[str], cols: int, lines: TextLines) -> np.ndarray:
    if len(cells) < cols or any(c.strip() for c in cells[cols:]):
        filled = len([c for c in cells if c.strip()])
        raise lines.fail(f"{filled} values, expected {cols} (Columns)")
    row = numbers(cells[:cols], lines)
    check_pressures(row, lines)
    return row


def _finish(
    sensor: _Sensor, grid: list[np.ndarray], fields: dict[str, str], lines: TextLines
) -> None:
    sensor.values.add(np.concatenate(grid))
    text = fields.get(_LOAD)
    sensor.load.add(np.array([np.nan if text is None else _load(text, lines)]))


def _load(text: str, lines: TextLines) -> float:
    load = np.array([field_number(text, lines, "Est. Load")])
    check_readings(load, lines, first_column=2)
    return float(load[0])


def _close_frame(sensors: dict[str, _Sensor], frame_numbers: list[int], lines: TextLines) -> None:
    """Every sensor seen so far has one grid per frame so far."""
    for foot, sensor in sensors.items():
        if len(sensor.values) != len(frame_numbers):
            shown = frame_numbers[-1] if frame_numbers else "?"
            raise lines.fail(f"frame {shown} has no complete {foot} ({sensor.name}) grid")


def _recording(
    path: Path,
    top: dict[str, str],
    sensors: dict[str, _Sensor],
    stamps: list[datetime],
    frame_numbers: list[int],
) -> VendorRecording:
    units = top.get("Units", "").strip()
    if not units:
        raise InputError(path, "no 'Units:' line: the units are unknown")
    scale = kpa_per_unit(units)
    feet: dict[str, FootData] = {}
    for foot, sensor in sensors.items():
        values = sensor.values.array().reshape(-1, sensor.rows, sensor.cols)
        load = sensor.load.array()[:, 0].astype(np.float64)
        feet[foot] = FootData(
            values,
            units,
            scale,
            orientation=Orientation(toes_first_row=True, medial_first_col=foot == "right"),
            sensel_area_mm2=sensor.area_mm2,
            total_force_n=None if np.isnan(load).all() else load,
        )
    start = stamps[0]
    times = np.array([(s - start).total_seconds() for s in stamps])
    span = float(times[-1]) if times.size > 1 else 0.0
    rate = (times.size - 1) / span if span > 0 else 0.0
    info: dict[str, Any] = {
        "fields": top,
        "sensors": {foot: s.name for foot, s in sensors.items()},
        "sensor_type": ", ".join(s.name for s in sensors.values()),
        "start": start.isoformat(timespec="milliseconds"),
        "frame_numbers": [frame_numbers[0], frame_numbers[-1]],
        "rate_from": "time stamps (ms)",
    }
    return VendorRecording("xsensor", path, times, feet, rate, units, [], info)
