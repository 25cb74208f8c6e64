"""Reading the containers: CSV (line and column kept for errors), ``.npz`` and HDF5.

CSV files are comma separated with an optional header line (taken as one
when any of its cells is not a number). Values are parsed by numpy's C
reader; only when that fails is the file walked in Python to name the
first bad cell. HDF5 needs h5py (the ``[import]`` extra), imported only
when an HDF5 file is read.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scotti.importers.errors import InputError

HDF5_SUFFIXES = (".h5", ".hdf5", ".hdf")


@dataclass(frozen=True)
class CsvTable:
    """The numeric body of a CSV file, with where each value came from."""

    path: Path
    header: list[str] | None  # column names, when the file has a header line
    values: np.ndarray  # (n, k) float64
    lines: np.ndarray  # (n,) int64, 1-based line number of each row
    header_line: int | None = None  # 1-based line of the header, when there is one

    def column_of(self, name_or_index: str | int) -> int:
        """0-based index of a column given by name (header) or by 0-based index."""
        if isinstance(name_or_index, int):
            if not 0 <= name_or_index < self.values.shape[1]:
                problem = f"no column {name_or_index} (the file has {self.values.shape[1]})"
                raise InputError(self.path, problem)
            return name_or_index
        if self.header is None or name_or_index not in self.header:
            problem = f"no column named {name_or_index!r}" + (
                "" if self.header is not None else " (the file has no header line)"
            )
            raise InputError(self.path, problem)
        return self.header.index(name_or_index)

    def describe_column(self, index: int) -> str:
        """1-based column number, with its header name when there is one."""
        if self.header is not None and index < len(self.header):
            return f"{index + 1} ({self.header[index]})"
        return str(index + 1)

    def fail(self, row: int, column: int, problem: str) -> InputError:
        return InputError(
            self.path,
            problem,
            line=int(self.lines[row]),
            column=self.describe_column(column),
        )


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def read_csv(path: Path, expected_columns: int | None = None) -> CsvTable:
    """A CSV file's numbers; ``InputError`` naming the line and column of any mistake."""
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(path, f"cannot read ({exc.__class__.__name__})") from None
    all_lines = text.splitlines()
    numbered = [(i + 1, line) for i, line in enumerate(all_lines) if line.strip()]
    if not numbered:
        raise InputError(path, "the file is empty")
    header: list[str] | None = None
    header_line: int | None = None
    first_cells = [c.strip() for c in numbered[0][1].split(",")]
    if not all(_is_number(c) for c in first_cells):
        header, header_line = first_cells, numbered[0][0]
        numbered = numbered[1:]
    if not numbered:
        raise InputError(path, "no data lines after the header")
    width = expected_columns or (len(header) if header is not None else None)
    width = width or numbered[0][1].count(",") + 1
    commas = np.fromiter((line.count(",") for _, line in numbered), np.int64, len(numbered))
    wrong = np.flatnonzero(commas != width - 1)
    if wrong.size:
        number = numbered[int(wrong[0])][0]
        got = int(commas[wrong[0]]) + 1
        raise InputError(path, f"{got} columns, expected {width}", line=number)
    lines = np.array([n for n, _ in numbered], dtype=np.int64)
    try:
        values = np.loadtxt([line for _, line in numbered], delimiter=",", ndmin=2)
    except ValueError:
        values = np.empty(0)
    if values.shape != (len(numbered), width):
        _raise_bad_cell(path, numbered, header)
    return CsvTable(path, header, np.asarray(values, dtype=np.float64), lines, header_line)


def _raise_bad_cell(path: Path, numbered: list[tuple[int, str]], header: list[str] | None) -> None:
    for number, line in numbered:
        for col, cell in enumerate(line.split(",")):
            if not _is_number(cell.strip()):
                name = f" ({header[col]})" if header is not None and col < len(header) else ""
                raise InputError(
                    path,
                    f"{cell.strip()!r} is not a number",
                    line=number,
                    column=f"{col + 1}{name}",
                )
    raise InputError(path, "cannot parse the numbers")  # pragma: no cover - loadtxt agreed


def load_arrays(path: Path, keys: list[str]) -> dict[str, np.ndarray]:
    """Named arrays from an ``.npz`` (names) or an HDF5 file (dataset paths).

    A key ending in ``?`` is optional (left out of the result when absent).
    """
    suffix = path.suffix.lower()
    if not path.is_file():
        raise InputError(path, "no such file")
    found: dict[str, np.ndarray] = {}
    if suffix == ".npz":
        try:
            with np.load(path, allow_pickle=False) as z:
                available = list(z.files)
                for key in keys:
                    name = key.rstrip("?")
                    if name in available:
                        found[name] = np.asarray(z[name])
        except (OSError, ValueError) as exc:
            raise InputError(path, f"not a readable .npz ({exc.__class__.__name__})") from None
    elif suffix in HDF5_SUFFIXES:
        available = _read_hdf5(path, [k.rstrip("?") for k in keys], found)
    else:
        raise InputError(path, f"unknown file type {suffix!r} (.csv, .npz, .h5, .hdf5)")
    for key in keys:
        if not key.endswith("?") and key not in found:
            shown = ", ".join(available[:12]) + (" ..." if len(available) > 12 else "")
            raise InputError(path, f"no array {key!r} (it has: {shown or 'nothing'})")
    return found


def _read_hdf5(path: Path, names: list[str], found: dict[str, np.ndarray]) -> list[str]:
    try:
        import h5py  # the [import] extra; only HDF5 files need it
    except ModuleNotFoundError:
        raise InputError(path, "reading HDF5 needs h5py: pip install 'scotti[import]'") from None
    available: list[str] = []
    try:
        with h5py.File(path, "r") as f:
            f.visit(
                lambda name: available.append(name) if isinstance(f[name], h5py.Dataset) else None
            )
            for name in names:
                if name in f and isinstance(f[name], h5py.Dataset):
                    found[name] = np.asarray(f[name][()])
    except OSError as exc:
        raise InputError(path, f"not a readable HDF5 file ({exc})") from None
    return available


def first_bad(values: np.ndarray) -> tuple[int, ...] | None:
    """Index of the first NaN, infinite or negative value (C order), None when all good."""
    if values.size == 0:
        return None
    low, high = values.min(), values.max()  # NaN propagates: two passes, no temporaries
    if np.isfinite(low) and np.isfinite(high) and low >= 0:
        return None
    bad = ~np.isfinite(values) | (values < 0)
    if not bad.any():
        return None
    flat = int(np.argmax(bad.reshape(-1)))
    return tuple(int(i) for i in np.unravel_index(flat, values.shape))


def describe_value(value: float) -> str:
    if math.isnan(value):
        return "NaN"
    if math.isinf(value):
        return "an infinite value"
    return f"negative value {value:g}"
