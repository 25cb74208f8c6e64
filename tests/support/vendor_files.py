"""Small vendor exports written as each vendor's software writes them (importers/vendors/)."""

from __future__ import annotations

import gzip
from collections.abc import Sequence
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np


def write_pedar(
    path: Path, times: np.ndarray, feet: dict[str, np.ndarray], units: str = "kPa"
) -> Path:
    """novel pedar .asc: ``feet`` "left"/"right" -> (N, 99) values."""
    period = float(times[1] - times[0]) if times.size > 1 else 0.01
    lines = [
        "file name:  TEST.sol\tdate/time  25.04.23 10.49",
        "sensor type:  y-1865l-1870r-pxf306-11mar2021 ",
        f"total time [secs]:  {times[-1]:.3f}\ttime per frame [secs]:  {period:.5f}"
        f"\tscanning rate [Hz]:   {round(1 / period)}",
        f"pressure values in  {units}",
        "",
        "mask definition: ",
    ]
    for foot in feet:
        lines.append(f"{foot} insole: " + "".join(f"{k}," for k in range(1, 100)))
    lines.append("")
    header = "time[secs]    \t" + "".join(f"{k:7d}\t" for _ in feet for k in range(1, 100))
    lines.append(header)
    both = np.concatenate([feet[f] for f in feet], axis=1)
    for t, row in zip(times, both, strict=True):
        lines.append(f"{t:12.5f}\t" + "".join(f"{v:7.3f}\t" for v in row))
    path.write_text("\n".join(lines) + "\n")
    return path


def write_fscan(
    path: Path,
    frames: np.ndarray,
    *,
    period: float = 0.032,
    units: str = "KPa",
    calibration: str | None = "75.0001 (Kgs) 4798 (Raw Sum) 240 (Number of Loaded Cells)",
    mirror_col: int = 0,
    start_frame: int = 1,
    declared_frames: int | None = None,
) -> Path:
    """Tekscan .asf: ``frames`` (N, rows, cols), NaN where no sensel is (written ``B``)."""
    n, rows, cols = frames.shape
    head = [
        "DATA_TYPE MOVIE",
        "VERSION Tekscan Pressure Measurement System 6.33",
        "SENSOR_TYPE FSCAN",
        f"ROWS {rows}",
        f"COLS {cols}",
        "ROW_SPACING 5.08 mm",
        "COL_SPACING 5.08 mm",
        "SENSEL_AREA 25.8064 mm2",
        f"SECONDS_PER_FRAME {period}",
    ]
    if calibration is not None:
        head.append(f"CALIBRATION_POINT_1 {calibration}")
    head += [
        "COMMENTS:",
        "overground walk test",
        f"START_FRAME {start_frame}",
        f"END_FRAME {start_frame + (declared_frames or n) - 1}",
        f"UNITS {units}",
        "MIRROR_ROW 0",
        f"MIRROR_COL {mirror_col}",
        "ASCII_DATA @@",
        "",
    ]
    body = []
    for k, frame in enumerate(frames):
        body.append(f"Frame {start_frame + k}")
        for row in frame:
            body.append(",".join("B" if np.isnan(v) else f"{v:g}" for v in row))
        body.append("")
    path.write_text("\n".join(head + body + ["@@", ""]))
    return path


def insole_outline(rows: int, cols: int, foot: str = "left") -> np.ndarray:
    """A sensor outline seen from above, toes at row 0: wider and longer on the big-toe side."""
    mask = np.ones((rows, cols), dtype=bool)
    toe_rows = max(1, rows // 8)
    for r in range(toe_rows):  # the toe end slopes back from the big toe to the fifth
        cut = (toe_rows - r) * cols // (2 * toe_rows)
        mask[r, :cut] = False  # lateral side of a left insole (seen from above) is column 0
    mask[-1, 0] = mask[-1, -1] = False
    return mask if foot == "left" else mask[:, ::-1]


def write_xsensor(
    path: Path, start: datetime, period_s: float, grids: dict[str, np.ndarray], units: str = "mmHg"
) -> Path:
    """XSENSOR X4 .csv: ``grids`` "LF"/"RF" -> (N, rows, cols), blank comma lines between."""
    blank = "," * 19
    lines = ['File:,"C:\\data\\walk,1,test.XSN"' + "," * 18, blank, f"Units:,{units}" + "," * 18]
    lines += [blank, "Threshold:,51.72" + "," * 18, blank]
    n = next(iter(grids.values())).shape[0]
    for k in range(n):
        stamp = start + timedelta(seconds=k * period_s)
        lines += [f"FRAME,{1000 + k}" + "," * 18, blank]
        lines += [f"Date, {stamp:%Y %b %d}" + "," * 18, blank]
        lines += [f"Time, {stamp:%H:%M:%S}.{stamp.microsecond // 1000:03d}" + "," * 18, blank]
        for side, frames in grids.items():
            rows, cols = frames.shape[1:]
            lines += [f"SENSOR,HX210.11.31.M11-DFM-{side} S0073" + "," * 18, blank]
            lines += [f"Rows,{rows}", blank, f"Columns,{cols}", blank]
            lines += ["Sensel Width (cm),0.86", blank, "Sensel Height (cm),0.86", blank]
            lines += [f"Est. Load (N),{frames[k].sum():.2f}", blank, "SENSELS" + "," * 19, blank]
            for row in frames[k]:
                lines += [",".join(f"{v:g}" for v in row) + "," * (20 - cols), blank]
            lines += ["GROUP,1", blank, f"Name,{side} Heel", blank, "SENSELS", blank]
            lines += [",".join(["0"] * 20), "0,0,0", blank]
    path.write_text("\ufeff" + "\n".join(lines) + "\n", encoding="utf-8")
    return path


MOTICON_CHANNELS = ("acceleration X[g]", "acceleration Y[g]", "acceleration Z[g]")


def write_moticon(
    path: Path,
    times: np.ndarray,
    feet: dict[str, np.ndarray],
    *,
    missing: dict[str, Sequence[int]] | None = None,
    steps: dict[int, int] | None = None,
    events: dict[int, tuple[str, str, str]] | None = None,
    tag: str = "normal",
    size: int = 7,
) -> Path:
    """Moticon OpenGo .txt: ``feet`` -> (N, 16) N/cm²; ``missing`` rows left empty per foot;
    ``steps`` row -> code (11/15 left, 21/25 right); ``events`` row -> (group, label, value)."""
    missing = missing or {}
    columns = ["time"]
    for foot in ("left", "right"):
        columns += [f"{foot} pressure {k}[N/cm²]" for k in range(1, 17)]
        columns += [f"{foot} {c}" for c in MOTICON_CHANNELS]
        columns += [f"{foot} total force[N]"]
    columns += ["right steps[]", "left steps[]"]
    groups = sorted({g for g, _, _ in (events or {}).values()})
    for g in groups:
        columns += [f"{g} label[]", f"{g}[]"]
    lines = [
        "# Start timestamp: 1663250316241",
        "# Start time: 15.09.2022 15:58:36.241",
        f"# Duration: 00:{times[-1]:06.3f}",
        "# Sensor insoles: Left SN1, Right SN2",
        f"# Size: {size}",
        "# Recording type: live",
        "# Name: walking",
        "# Notes: test",
        f"# Tag: {tag}",
        "# " + "\t".join(columns),
    ]
    for i, t in enumerate(times):
        cells = [f"{t:.2f}"]
        for foot in ("left", "right"):
            width = 16 + len(MOTICON_CHANNELS) + 1
            if foot not in feet or i in missing.get(foot, ()):
                cells += [""] * width
                continue
            values = feet[foot][i]
            cells += [f"{v:.2f}" for v in values] + ["0.1", "-0.2", "0.98"]
            cells.append(f"{values.sum() * 3.0:.2f}")
        code = (steps or {}).get(i)
        right = f"{code:.2f}" if code in (21, 25) else ""
        left = f"{code:.2f}" if code in (11, 15) else ""
        cells += [right, left]
        for g in groups:
            e = (events or {}).get(i)
            cells += [e[1], e[2]] if e and e[0] == g else ["", ""]
        lines.append("\t".join(cells))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def write_gaitpdb(
    path: Path, times: np.ndarray, left: np.ndarray, right: np.ndarray, *, gz: bool = False
) -> Path:
    """gaitpdb: time, 8 + 8 sensor forces (N), the two totals; tab separated; gzip if asked."""
    rows = np.column_stack([times, left, right, left.sum(axis=1), right.sum(axis=1)])
    text = "\n".join(
        "\t".join(f"{v:.4f}" if j == 0 else f"{v:.2f}" for j, v in enumerate(r)) for r in rows
    )
    data = (text + "\n").encode()
    path.write_bytes(gzip.compress(data) if gz else data)
    return path
