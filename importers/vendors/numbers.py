"""Cells of a text line into numbers, with the column of the first one that is not."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Final

import numpy as np
from scotti.importers.vendors.lines import TextLines

# No sensor reads this much in any unit (Pa, mmHg, N, ...); values stay far inside float32
# (3.4e38), so casting, unit factors and sums over frames cannot overflow.
MAX_READING: Final = 1e15


def numbers(
    cells: Sequence[str], lines: TextLines, *, first_column: int = 1, empty_is_nan: bool = False
) -> np.ndarray:
    """float64 of each cell; an InputError naming the line and 1-based column otherwise."""
    if not empty_is_nan:
        try:  # numpy's own parser first; the slow walk below only to name a bad cell
            return np.array(cells, dtype=np.float64)
        except ValueError:
            pass
    out = np.empty(len(cells))
    for i, cell in enumerate(cells):
        text = cell.strip()
        if not text and empty_is_nan:
            out[i] = math.nan
            continue
        try:
            out[i] = float(text)
        except ValueError:
            shown = text if len(text) <= 20 else text[:17] + "..."
            raise lines.fail(f"{shown!r} is not a number", column=first_column + i) from None
    return out


def check_pressures(
    values: np.ndarray, lines: TextLines, *, first_column: int = 1, allow_nan: bool = False
) -> None:
    """Pressures and forces are finite, not negative and in range (NaN allowed where a cell
    was empty)."""
    _check(values, lines, first_column, allow_nan, negative=False)


def check_readings(values: np.ndarray, lines: TextLines, *, first_column: int = 1) -> None:
    """Readings of either sign (a vendor's force estimate) are finite and in range."""
    _check(values, lines, first_column, False, negative=True)


def _check(
    values: np.ndarray, lines: TextLines, first_column: int, allow_nan: bool, negative: bool
) -> None:
    # One pass of comparisons (NaN compares false): this runs on every line of a file.
    fine = (np.abs(values) if negative else values) <= MAX_READING
    if not negative:
        fine &= values >= 0
    bad = ~fine
    if allow_nan:
        bad &= ~np.isnan(values)
    if bad.any():
        i = int(np.argmax(bad))
        value = float(values[i])
        if math.isnan(value):
            problem = "NaN"
        elif math.isinf(value):
            problem = "an infinite value"
        elif value < 0 and not negative:
            problem = f"negative value {value:g}"
        else:
            problem = f"value {value:g} is past any sensor's range ({MAX_READING:g})"
        raise lines.fail(problem, column=first_column + i)


def field_number(text: str, lines: TextLines, what: str) -> float:
    """The first number in ``text`` (a header field's value), or an error naming ``what``."""
    for token in text.replace(",", " ").split():
        try:
            value = float(token)
        except ValueError:
            continue
        if math.isfinite(value):
            return value
    raise lines.fail(f"{what}: no number in {text.strip()[:40]!r}")


class Clock:
    """A file's time stamps, line by line: finite and strictly increasing, or the line says why."""

    def __init__(self) -> None:
        self.last: float | None = None

    def check(self, t: float, lines: TextLines, column: int = 1) -> None:
        if not math.isfinite(t):
            raise lines.fail("time stamp is not a number", column=column)
        if self.last is not None and t <= self.last:
            kind = "duplicate" if t == self.last else "earlier than the one before"
            raise lines.fail(
                f"time stamp {kind} ({t:.9g} s after {self.last:.9g} s)", column=column
            )
        self.last = t
