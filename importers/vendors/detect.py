"""Which format a file is, from its own first lines (the name is only a tie-breaker).

Each vendor's export starts in its own way; these are the marks looked for
in the first 16 kB (a gzip file inflated):

| format | mark |
|---|---|
| pedar | ``file name:`` / ``sensor type:`` lines and a ``time[`` column line (novel .asc) |
| fscan | ``DATA_TYPE`` or a ``VERSION Tekscan`` line, and ``ASCII_DATA`` |
| xsensor | ``FRAME,`` / ``SENSOR,`` / ``SENSELS`` rows (XSENSOR X4 CSV) |
| moticon | ``# Start time:`` and ``# Sensor insoles:`` (OpenGo text export) |
| gaitpdb | 19 numbers a line, columns 18 and 19 the sums of 2-9 and 10-17 |
| table | ``.npz``, ``.h5``/``.hdf5``, or any other ``.csv``: the generic reader |
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Final

from scotti.importers.errors import InputError
from scotti.importers.tables import HDF5_SUFFIXES
from scotti.importers.vendors.lines import head_text

VENDOR_FORMATS: Final = ("pedar", "fscan", "xsensor", "moticon", "gaitpdb")
FORMATS: Final = (*VENDOR_FORMATS, "table")
_TABLE_SUFFIXES: Final = (".npz", *HDF5_SUFFIXES)


def detect(path: Path) -> str:
    """The format of ``path``; an InputError when nothing here reads it."""
    if not path.is_file():
        raise InputError(path, "no such file")
    if path.suffix.lower() in _TABLE_SUFFIXES:
        return "table"
    head = head_text(path)
    found = _from_text(head)
    if found:
        return found
    if path.suffix.lower() == ".csv":
        return "table"
    shown = ", ".join(VENDOR_FORMATS)
    problem = f"not a format this importer knows ({shown}, or a CSV/.npz/HDF5 table); "
    problem += "--format names it"
    raise InputError(path, problem)


def _from_text(head: str) -> str | None:
    lines = head.splitlines()
    lowered = [line.strip().lower() for line in lines[:40]]
    if any(x.startswith("file name:") for x in lowered) and any(
        x.startswith("sensor type:") for x in lowered
    ):
        return "pedar"
    if (lowered and lowered[0].startswith("data_type")) or any(
        x.startswith("version tekscan") for x in lowered
    ):
        return "fscan"
    if any(x.startswith("# start time:") for x in lowered) and any(
        x.startswith("# sensor insoles:") for x in lowered
    ):
        return "moticon"
    cells = [line.split(",", 1)[0].strip().upper() for line in lines[:400]]
    if {"FRAME", "SENSOR"} <= set(cells) and ("SENSELS" in cells or "FILE:" in cells):
        return "xsensor"
    if _gaitpdb(lines[:5]):
        return "gaitpdb"
    return None


_NUMBER: Final = re.compile(r"^[-+]?\d*\.?\d+(?:[eE][-+]?\d+)?$")


def _gaitpdb(lines: list[str]) -> bool:
    rows = [line.split() for line in lines if line.strip()]
    full = [r for r in rows[:-1] if r] or rows[:1]  # the last may be cut mid-line
    if not full:
        return False
    for cells in full:
        if len(cells) != 19 or not all(_NUMBER.match(c) for c in cells):
            return False
        v = [float(c) for c in cells]
        if abs(sum(v[1:9]) - v[17]) > 0.5 or abs(sum(v[9:17]) - v[18]) > 0.5:
            return False
    return True
