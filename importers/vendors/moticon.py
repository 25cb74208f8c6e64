"""Moticon OpenGo text export (.txt): 16 cells a foot in N/cm², with IMU, force, COP, events.

    # Start time: 27.09.2023 10:21:14.922
    # Duration: 00:17.496
    # Sensor insoles: Left SN5968, Right SN9171
    # Size: 7
    # Tag: normal
    # time<TAB>left pressure 1[N/cm²]<TAB>...<TAB>left total force[N]<TAB>...<TAB>right steps[]
    0.00<TAB><TAB><TAB>...<TAB>6.50<TAB>6.50 ...

``# name: value`` header lines, then the column line (``# time`` and the
channels, each ``[unit]``), then one tab-separated line per sample on one
clock for both insoles. A cell is empty where an insole sent nothing at
that moment: each insole streams on its own radio link, and the export
merges them. So each foot keeps the samples it has, the holes between are
filled linearly, and the recording is cut to where every insole present
has started and not yet stopped (what is cut is said in ``info``).

Events: a pair of columns ``NAME label[]`` and ``NAME[]`` (OpenGo's event
groups) gives ``NAME: label value``; the ``steps`` channels give each foot's
heel strikes and toe-offs (11/15 left, 21/25 right, as the moticon-opengo
package reads them). The IMU, the centre of pressure and the COP velocity
are listed in ``info`` by name; the model's contract has no place for them.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np
from scotti.importers.errors import InputError, clip
from scotti.importers.vendors.lines import Rows, TextLines
from scotti.importers.vendors.numbers import (
    MAX_READING,
    Clock,
    check_pressures,
    check_readings,
    numbers,
)
from scotti.importers.vendors.recording import FOOT_NAMES, FootData, VendorRecording, kpa_per_unit

CELLS: Final = 16
LAYOUT: Final = "moticon-opengo-16"
MAX_STEP_CODE: Final = 999  # OpenGo's codes are two digits
STEP_EVENTS: Final = {
    11: "left heel strike",
    15: "left toe off",
    21: "right heel strike",
    25: "right toe off",
}
_CHANNEL: Final = re.compile(r"^(left|right) (.+?)\s*\[(.*)\]$")
_PRESSURE: Final = re.compile(r"^pressure (\d+)$")


@dataclass
class _Columns:
    """Where each channel the import reads sits in a data line."""

    count: int = 0
    time: int = 0
    pressure: dict[str, list[int]] = field(default_factory=dict)  # foot -> 16 columns in order
    force: dict[str, int] = field(default_factory=dict)  # foot -> total force column
    steps: list[int] = field(default_factory=list)
    events: list[tuple[int, str]] = field(default_factory=list)  # label column, group name
    units: str = ""
    other: list[str] = field(default_factory=list)  # channels listed, not imported


def read_moticon(path: Path) -> VendorRecording:
    header: dict[str, str] = {}
    events: list[tuple[float, str]] = []
    with TextLines(path) as lines:
        columns: _Columns | None = None
        body: Rows | None = None
        clock = Clock()
        for _, line in lines:
            if line.startswith("#"):
                text = line[1:].strip()
                if text.startswith("time\t") or text == "time":
                    columns = _columns(text.split("\t"), lines)
                    body = Rows(1 + 2 * (CELLS + 1), np.float64)  # the time column needs 64 bits
                elif ":" in text:
                    name, value = text.split(":", 1)
                    header[name.strip()] = value.strip()
                continue
            if not line.strip():
                continue
            if columns is None or body is None:
                raise lines.fail("data before the '# time' column line: not a Moticon export")
            row = _row(line, columns, lines, events)
            clock.check(float(row[0]), lines, columns.time + 1)
            body.add(row)
        if columns is None or body is None:
            raise InputError(path, "no '# time' column line: not a Moticon text export")
        if not len(body):
            raise InputError(path, "no samples after the column line", line=lines.number)
    return _recording(path, header, columns, body.array(), events)


def _columns(names: list[str], lines: TextLines) -> _Columns:
    while names and not names[-1].strip():
        names = names[:-1]
    out = _Columns(count=len(names))
    labels = {
        i
        for i in range(len(names) - 1)
        if names[i].strip().endswith(" label[]")
        and names[i].strip()[: -len(" label[]")] == names[i + 1].strip()[: -len("[]")]
    }
    cells: dict[str, dict[int, int]] = {}
    units: set[str] = set()
    for i, raw in enumerate(names[1:], start=1):
        name = raw.strip()
        if i in labels:
            out.events.append((i, name[: -len(" label[]")]))
            continue
        if i - 1 in labels:
            continue
        found = _CHANNEL.match(name)
        if not found:
            out.other.append(name)
            continue
        foot, channel, unit = found.groups()
        cell = _PRESSURE.match(channel)
        if cell:
            cells.setdefault(foot, {})[int(cell.group(1))] = i
            units.add(unit)
        elif channel == "total force":
            out.force[foot] = i
        elif channel == "steps":
            out.steps.append(i)
        else:
            out.other.append(name)
    for foot, by_number in cells.items():
        if sorted(by_number) != list(range(1, CELLS + 1)):
            raise lines.fail(f"{foot} pressure columns {sorted(by_number)}, expected 1..{CELLS}")
        out.pressure[foot] = [by_number[k] for k in range(1, CELLS + 1)]
    if not out.pressure:
        raise lines.fail("no 'left pressure N' or 'right pressure N' columns")
    if len(units) != 1:
        raise lines.fail(f"pressure columns in several units: {', '.join(sorted(units))}")
    out.units = units.pop()
    return out


def _row(
    line: str, columns: _Columns, lines: TextLines, events: list[tuple[float, str]]
) -> np.ndarray:
    cells = line.split("\t")
    if len(cells) < columns.count or any(c.strip() for c in cells[columns.count :]):
        raise lines.fail(f"{len(cells)} cells, expected {columns.count} (the column line)")
    out = np.full(1 + 2 * (CELLS + 1), np.nan)
    out[0] = numbers([cells[columns.time]], lines)[0]
    for k, foot in enumerate(FOOT_NAMES):
        where = columns.pressure.get(foot)
        if where is None:
            continue
        raw = [cells[i] for i in where]
        filled = [bool(c.strip()) for c in raw]
        if not any(filled):
            continue  # this insole sent nothing at this moment
        if not all(filled):
            missing = where[filled.index(False)]
            raise lines.fail(f"{foot} pressure cell empty beside others", column=missing + 1)
        values = numbers(raw, lines)
        bad = ~((values >= 0) & (values <= MAX_READING))  # NaN too
        if bad.any():  # the columns are not adjacent: name the bad one's own
            j = int(np.argmax(bad))
            check_pressures(values[j : j + 1], lines, first_column=where[j] + 1)
        start = 1 + k * (CELLS + 1)
        out[start : start + CELLS] = values
        if foot in columns.force and cells[columns.force[foot]].strip():
            index = columns.force[foot]
            force = numbers([cells[index]], lines, first_column=index + 1)
            check_readings(force, lines, first_column=index + 1)
            out[start + CELLS] = force[0]
    t = float(out[0])
    for i in columns.steps:
        if cells[i].strip():
            code = numbers([cells[i]], lines, first_column=i + 1)[0]
            if not np.isfinite(code) or code != round(code) or abs(code) > MAX_STEP_CODE:
                raise lines.fail(f"step code {code:g} is not a code", column=i + 1)
            events.append((t, STEP_EVENTS.get(int(code), f"step code {int(code)}")))
    for i, group in columns.events:
        if cells[i].strip():
            value = cells[i + 1].strip()
            events.append((t, f"{group}: {cells[i].strip()} {value}".strip()))
    return out


def _recording(
    path: Path,
    header: dict[str, str],
    columns: _Columns,
    table: np.ndarray,
    events: list[tuple[float, str]],
) -> VendorRecording:
    times = table[:, 0].astype(np.float64)
    present: dict[str, np.ndarray] = {}
    for k, foot in enumerate(FOOT_NAMES):
        if foot in columns.pressure:
            has = ~np.isnan(table[:, 1 + k * (CELLS + 1)])
            if has.any():
                present[foot] = has
    if not present:
        raise InputError(path, "no pressure values for either insole")
    first = max(int(np.argmax(has)) for has in present.values())
    last = min(has.size - 1 - int(np.argmax(has[::-1])) for has in present.values())
    if first > last:
        raise InputError(path, "the two insoles never stream at the same time")
    keep = slice(first, last + 1)
    kept_times = times[keep]
    scale = kpa_per_unit(columns.units)
    feet: dict[str, FootData] = {}
    holes: dict[str, Any] = {}
    for k, foot in enumerate(FOOT_NAMES):
        if foot not in present:
            continue
        start = 1 + k * (CELLS + 1)
        block = table[keep, start : start + CELLS + 1]
        has = present[foot][keep]
        filled = _fill(kept_times, block, has)
        force = filled[:, CELLS].astype(np.float64)
        feet[foot] = FootData(
            np.ascontiguousarray(filled[:, :CELLS]),
            columns.units,
            scale,
            layout=LAYOUT,
            layout_size=clip(header["Size"]) if header.get("Size") else None,
            total_force_n=None if np.isnan(force).any() else force,
        )
        holes[foot] = _holes(kept_times, has)
    start_time = _start(header)
    info: dict[str, Any] = {
        "header": header,
        "tags": [header["Tag"]] if header.get("Tag") else [],
        "sensor_type": f"Moticon OpenGo, size {header.get('Size', '?')}",
        "insoles": header.get("Sensor insoles", ""),
        "channels_not_imported": columns.other,
        "samples": int(times.size),
        "cut_s": [
            round(float(kept_times[0] - times[0]), 3),
            round(float(times[-1] - kept_times[-1]), 3),
        ],
        "filled": holes,
    }
    if start_time is not None:
        info["start_unix"] = start_time
    rate = _rate(kept_times)
    return VendorRecording("moticon", path, kept_times, feet, rate, columns.units, events, info)


def _fill(t: np.ndarray, block: np.ndarray, has: np.ndarray) -> np.ndarray:
    """Each column linearly through the samples the insole sent."""
    if has.all():
        return block.astype(np.float32)
    out = np.empty(block.shape, dtype=np.float32)
    for c in range(block.shape[1]):
        column = block[has, c]
        good = ~np.isnan(column)
        if not good.any():
            out[:, c] = np.nan
            continue
        out[:, c] = np.interp(t, t[has][good], column[good])
    return out


def _holes(t: np.ndarray, has: np.ndarray) -> dict[str, Any]:
    missing = int((~has).sum())
    if not missing:
        return {"samples": 0, "longest_s": 0.0}
    present_t = t[has]
    longest = float(np.diff(present_t).max()) if present_t.size > 1 else 0.0
    return {"samples": missing, "longest_s": round(longest, 3)}


def _start(header: dict[str, str]) -> float | None:
    stamp = header.get("Start timestamp")
    if stamp:
        try:
            return float(stamp) / 1000.0  # ms since 1970
        except ValueError:
            pass
    return None


def _rate(times: np.ndarray) -> float:
    if times.size < 2:
        return 0.0
    return float(round(1.0 / float(np.median(np.diff(times))), 3))
