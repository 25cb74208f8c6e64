"""PhysioNet gaitpdb (Ultraflex insoles, Infotronic): 8 force sensors a foot, in newtons.

    0.0000<TAB>199.1<TAB>87.34<TAB>...<TAB>662.2<TAB>748        (19 columns, no header)

One line per sample at 100 Hz: the time in seconds, the vertical force on
each of the 8 sensors under the left foot, the 8 under the right foot, then
each foot's total (the sum of its 8): PhysioNet's ``format.txt``. Files are
often kept gzipped (``.txt.gz``); either is read. The sensors are points,
not areas: ``importers.layouts`` places them (layout ``gaitpdb-8``) and the
import scales each rendered foot to the file's own total.

Where the data set's ``demographics.txt`` lies beside the file, the
subject's row (by the file name's ``GaCo01`` part) goes into ``info``.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Final

import numpy as np
from scotti.importers.errors import InputError
from scotti.importers.vendors.lines import Rows, TextLines
from scotti.importers.vendors.numbers import Clock, check_pressures, numbers
from scotti.importers.vendors.recording import FootData, VendorRecording

SENSORS: Final = 8
COLUMNS: Final = 1 + 2 * SENSORS + 2
LAYOUT: Final = "gaitpdb-8"
RATE_HZ: Final = 100.0  # format.txt: "The sampling rate was 100 Hz"
TOTAL_TOLERANCE_N: Final = 0.5  # a total differs from its sensors' sum by rounding only
_SUBJECT: Final = re.compile(r"^((?:Ga|Ju|Si)(?:Co|Pt)\d+)_\d+", re.IGNORECASE)


def read_gaitpdb(path: Path) -> VendorRecording:
    with TextLines(path) as lines:
        body = Rows(COLUMNS, np.float64)
        clock = Clock()
        for _, line in lines:
            if not line.strip():
                continue
            cells = line.split()
            if len(cells) != COLUMNS:
                raise lines.fail(
                    f"{len(cells)} values, expected {COLUMNS} (time, 8 + 8 sensors, 2 totals)"
                )
            row = numbers(cells, lines)
            clock.check(float(row[0]), lines)
            check_pressures(row[1:], lines, first_column=2)
            for k, first in enumerate((1, 1 + SENSORS)):
                total = row[1 + 2 * SENSORS + k]
                if abs(row[first : first + SENSORS].sum() - total) > TOTAL_TOLERANCE_N:
                    side = ("left", "right")[k]
                    problem = f"{side} total {total:g} N is not the sum of its 8 sensors"
                    raise lines.fail(problem, column=2 + 2 * SENSORS + k)
            body.add(row)
        if not len(body):
            raise InputError(path, "no samples")
    table = body.array()
    times = table[:, 0]
    feet = {
        foot: FootData(
            table[:, 1 + k * SENSORS : 1 + (k + 1) * SENSORS].astype(np.float32),
            "N",
            None,  # newtons per sensor: kPa come from the layout's sensor areas
            layout=LAYOUT,
            total_force_n=table[:, 1 + 2 * SENSORS + k].copy(),
        )
        for k, foot in enumerate(("left", "right"))
    }
    info: dict[str, Any] = {
        "sensor_type": "Ultraflex (Infotronic), 8 sensors a foot",
        "rate_from": "PhysioNet format.txt (100 Hz)",
    }
    demographics = _demographics(path)
    if demographics:
        info["demographics"] = demographics
    return VendorRecording("gaitpdb", path, times, feet, RATE_HZ, "N", [], info)


def _demographics(path: Path) -> dict[str, str] | None:
    """The subject's row of demographics.txt beside the file, by column name."""
    found = _SUBJECT.match(path.name)
    table = path.parent / "demographics.txt"
    if not found or not table.is_file() or table.stat().st_size > 1 << 20:
        return None
    try:
        rows = [line.split("\t") for line in table.read_text(encoding="latin-1").splitlines()]
    except OSError:
        return None
    if not rows:
        return None
    names = [n.strip() for n in rows[0]]
    for row in rows[1:]:
        if row and row[0].strip().lower() == found.group(1).lower():
            return {n: v.strip() for n, v in zip(names, row, strict=False) if n and v.strip()}
    return None
