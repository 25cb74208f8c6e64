"""novel pedar ASCII export (.asc): 99 cells a foot, both feet or one, usually kPa.

    file name:  3DI_S001_V2_FE_2.sol<TAB>date/time  25.04.23 10.49
    sensor type:  y-1865l-1870r-pxf306-11mar2021
    total time [secs]:  15.050<TAB>time per frame [secs]:  0.01000<TAB>scanning rate [Hz]:   100
    pressure values in  kPa

    mask definition:
    left insole: 1,2,...,99,
    right insole: 1,2,...,99,

    time[secs]<TAB>1<TAB>...<TAB>99<TAB>1<TAB>...<TAB>99<TAB>
         0.01000<TAB> 32.500<TAB> 40.000 ...

The header is ``name: value`` fields, several to a line split by tabs; the
column line starts with ``time[``; then one line a frame: the time and the
cells, left insole's 99 then right insole's 99 (pressuRe's ``load_pedar``
reads them in that order too). A file of one insole has 99 cells and names
that insole alone in its mask definition.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Final

import numpy as np
from scotti.importers.errors import InputError
from scotti.importers.vendors.lines import Rows, TextLines, file_size, is_gzip
from scotti.importers.vendors.numbers import Clock, check_pressures, field_number, numbers
from scotti.importers.vendors.recording import FootData, VendorRecording, kpa_per_unit

CELLS: Final = 99  # sensors of a pedar-x insole
LAYOUT: Final = "pedar-x-99"
_MIN_VALUE_BYTES: Final = 2  # a cell's shortest form: one digit and a tab
_FIELD: Final = re.compile(r"^\s*([^:]+?)\s*:\s*(.*?)\s*$")  # name: value
_SPACED: Final = re.compile(r"^\s*(\S+)\s{2,}(.*?)\s*$")  # "date/time  25.04.23 10.49"


def read_pedar(path: Path) -> VendorRecording:
    fields: dict[str, str] = {}
    masks: dict[str, list[int]] = {}
    units: str | None = None
    with TextLines(path) as lines:
        width = 0
        body: Rows | None = None
        feet: list[str] = []
        clock = Clock()
        for _, line in lines:
            if body is None:
                if line.lstrip().lower().startswith("time["):
                    feet = _feet(line, masks, lines)
                    width = 1 + CELLS * len(feet)
                    _check_declared(path, fields, width, lines)
                    body = Rows(width, np.float64)  # the time column needs 64 bits
                    continue
                if line.lower().startswith("pressure values in"):
                    units = line[len("pressure values in") :].strip()
                    continue
                side = re.match(r"^\s*(left|right) insole\s*:(.*)$", line, re.IGNORECASE)
                if side:
                    masks[side.group(1).lower()] = _cell_list(side.group(2), lines)
                    continue
                for part in line.split("\t"):
                    found = _FIELD.match(part) or _SPACED.match(part)
                    if found and found.group(2):
                        fields[found.group(1).lower()] = found.group(2)
                continue
            if not line.strip():
                continue
            cells = line.rstrip("\t ").split("\t")
            if len(cells) != width:
                expected = f"{width} (time + {len(feet)} x {CELLS} cells)"
                raise lines.fail(f"{len(cells)} values, expected {expected}")
            row = numbers(cells, lines)
            clock.check(float(row[0]), lines)
            check_pressures(row[1:], lines, first_column=2)
            body.add(row)
        if body is None:
            raise InputError(path, "no column line starting with 'time[': not a pedar export")
        if not len(body):
            raise InputError(path, "no frames after the column line", line=lines.number)
    return _recording(path, body.array(), feet, fields, masks, units)


def _feet(header: str, masks: dict[str, list[int]], lines: TextLines) -> list[str]:
    count = len([c for c in header.split("\t")[1:] if c.strip()])
    if count == 2 * CELLS:
        return ["left", "right"]
    if count == CELLS and len(masks) == 1:
        return list(masks)
    if count == CELLS:
        raise lines.fail("99 cells, but the mask definition does not name one insole")
    raise lines.fail(f"{count} cell columns; a pedar-x file has {CELLS} or {2 * CELLS}")


def _cell_list(text: str, lines: TextLines) -> list[int]:
    try:
        return [int(c) for c in text.replace(" ", "").split(",") if c]
    except ValueError:
        raise lines.fail("mask definition: not a list of cell numbers") from None


def _check_declared(path: Path, fields: dict[str, str], width: int, lines: TextLines) -> None:
    """A declared length the file cannot hold is a broken header: say so before reading."""
    if "total time [secs]" not in fields or "time per frame [secs]" not in fields:
        return
    total = field_number(fields["total time [secs]"], lines, "total time")
    period = field_number(fields["time per frame [secs]"], lines, "time per frame")
    if period <= 0:
        raise lines.fail(f"time per frame {period:g} s")
    declared = total / period  # a float: a huge total over a tiny period is inf, not an error
    if round(declared, 0) * width * _MIN_VALUE_BYTES > file_size(path) and not is_gzip(path):
        problem = f"declares {declared:.0f} frames ({total:g} s), more than the file can hold"
        raise InputError(path, problem)


def _recording(
    path: Path,
    table: np.ndarray,
    feet: list[str],
    fields: dict[str, str],
    masks: dict[str, list[int]],
    units: str | None,
) -> VendorRecording:
    if units is None:
        raise InputError(path, "no 'pressure values in' line: the units are unknown")
    times = table[:, 0].astype(np.float64)
    scale = kpa_per_unit(units)
    size = insole_size(fields.get("sensor type", ""))
    out: dict[str, FootData] = {}
    for k, foot in enumerate(feet):
        values = table[:, 1 + k * CELLS : 1 + (k + 1) * CELLS]
        out[foot] = FootData(
            values.astype(np.float32), units, scale, layout=LAYOUT, layout_size=size
        )
    rate = _rate(fields, times)
    info: dict[str, Any] = {
        "fields": fields,
        "mask_definition": masks,
        "sensor_type": fields.get("sensor type", ""),
        "declared_frames": _declared(fields),
    }
    return VendorRecording("pedar", path, times, out, rate, units, [], info)


def insole_size(sensor_type: str) -> str | None:
    """The insole size a sensor type starts with: ``y-1865l-1870r-...`` is size y."""
    token = sensor_type.strip().split("-", 1)[0].strip().lower()
    return token if re.fullmatch(r"[a-z]{1,2}", token) else None


def _rate(fields: dict[str, str], times: np.ndarray) -> float:
    found = re.search(r"[\d.]+", fields.get("scanning rate [hz]", ""))
    if found:
        try:
            return float(found.group(0))
        except ValueError:
            pass
    span = float(times[-1] - times[0])
    return (times.size - 1) / span if span > 0 else 0.0


def _declared(fields: dict[str, str]) -> int | None:
    try:
        total = float(fields["total time [secs]"].split()[0])
        period = float(fields["time per frame [secs]"].split()[0])
    except (KeyError, ValueError, IndexError):
        return None
    return round(total / period) if period > 0 else None
