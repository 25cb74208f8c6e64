"""Reading the containers: CSV (line and column kept for errors), ``.npz`` and HDF5.

A CSV file is numbers in columns with an optional header line (taken as
one when any of its cells is not a number). Lines starting with ``#`` and
blank lines are skipped; the delimiter is a comma, a tab or a semicolon,
whichever splits the first data line into numbers; one delimiter at the
end of every line (an empty last column) is tolerated.

The file is read a block of whole lines at a time (``BLOCK_BYTES``), each
block parsed by numpy's C reader into rows of one array that grows within
the read's memory budget (``limits``); no row count is taken on trust, and
a line longer than ``MAX_LINE_BYTES`` is refused. Only a block the C reader
cannot parse is walked in Python, to name the first bad line and cell; an
error quotes at most ``errors.QUOTE_CHARS`` characters of the file.

``.npz`` and HDF5 files are read by ``arrays`` (sizes checked before anything
is allocated); ``load_arrays`` is theirs.
"""

from __future__ import annotations

import io
import math
import re
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO, Final

import numpy as np
from scotti.importers.arrays import HDF5_SUFFIXES as HDF5_SUFFIXES
from scotti.importers.arrays import load_arrays as load_arrays
from scotti.importers.errors import InputError, clip
from scotti.importers.limits import Budget, size_text

BLOCK_BYTES: Final = 1 << 20
MAX_LINE_BYTES: Final = 4 << 20  # a frame of the largest grid is some tens of kB
DELIMITERS: Final = (",", "\t", ";")  # in the order they are tried
_BOM: Final = b"\xef\xbb\xbf"
_HEADER_CELL_BYTES: Final = 96  # what one header name costs in memory, about
_DECIMAL_COMMA: Final = re.compile(r"[+-]?\d+,\d+")
_NEWLINE: Final = ord("\n")
FLOAT32_MAX: Final = float(np.finfo(np.float32).max)
# Bytes a blank line or a comment can start with (a line starting so is looked at closely).
_MAYBE_SKIPPED: Final = np.isin(np.arange(256), [ord(c) for c in "\n\r\t #"])


@dataclass(frozen=True)
class CsvTable:
    """The numeric body of a CSV file, with where each value came from."""

    path: Path
    header: list[str] | None  # column names, when the file has a header line
    values: np.ndarray  # (n, k) float64 (float32 when read ``narrow``)
    lines: np.ndarray  # (n,) int64, 1-based line number of each row
    header_line: int | None = None  # 1-based line of the header, when there is one
    wide: dict[int, np.ndarray] = field(default_factory=dict)  # column -> (n,) float64

    def column_of(self, name_or_index: str | int) -> int:
        """0-based index of a column given by name (header) or by 0-based index."""
        return _column_index(self.path, self.header, self.values.shape[1], name_or_index)

    def describe_column(self, index: int) -> str:
        """1-based column number, with its header name when there is one."""
        return _describe_column(self.header, index)

    def fail(self, row: int, column: int, problem: str) -> InputError:
        return InputError(
            self.path,
            problem,
            line=int(self.lines[row]),
            column=self.describe_column(column),
        )


def _column_index(
    path: Path, header: list[str] | None, width: int, name_or_index: str | int
) -> int:
    if isinstance(name_or_index, int):
        if not 0 <= name_or_index < width:
            raise InputError(path, f"no column {name_or_index} (the file has {width})")
        return name_or_index
    if header is None or name_or_index not in header:
        problem = f"no column named {clip(name_or_index)!r}" + (
            "" if header is not None else " (the file has no header line)"
        )
        raise InputError(path, problem)
    return header.index(name_or_index)


def _describe_column(header: list[str] | None, index: int) -> str:
    if header is not None and index < len(header):
        return f"{index + 1} ({clip(header[index], 40)})"
    return str(index + 1)


def is_number(cell: str) -> bool:
    """What numpy's reader takes for a number (Python's ``float`` also takes ``1_000``)."""
    if "_" in cell:
        return False
    try:
        float(cell)
    except ValueError:
        return False
    return True


def read_csv(
    path: Path,
    expected_columns: int | None = None,
    *,
    narrow: bool = False,
    wide: Sequence[str | int] = (),
) -> CsvTable:
    """A CSV file's numbers; ``InputError`` naming the line and column of any mistake.

    ``narrow``: the values are kept as float32 (half the memory of a pressure
    table, which is float32 from here on), and a value past float32's range is
    a mistake; the ``wide`` columns (names or 0-based indices: time stamps) are
    kept whole as well, in float64 (``CsvTable.wide``).
    """
    try:
        with path.open("rb") as f:
            return _CsvReader(path, f, expected_columns, narrow, wide).read()
    except OSError as exc:
        raise InputError(path, f"cannot read ({exc.__class__.__name__})") from None
    except MemoryError:  # the budget is a share of memory; the rest of the machine may be busy
        raise InputError(path, "out of memory while reading it") from None


# --- whole lines, a block at a time ---------------------------------------------------------


def _blocks(path: Path, f: BinaryIO) -> Iterator[bytes]:
    """The file as blocks of whole lines (the last one maybe without its newline)."""
    carry = b""
    offset = 0  # of the carry's first byte in the file
    data = f.read(BLOCK_BYTES).removeprefix(_BOM)
    while data:
        cut = data.rfind(b"\n") + 1
        if cut == 0:
            carry += data
            if len(carry) > MAX_LINE_BYTES:
                problem = f"a line longer than {size_text(MAX_LINE_BYTES)} (not a table of numbers)"
                raise InputError(path, problem, column=f"from byte {offset}")
        else:
            # One copy at most: the carried start of a line and the whole lines read now.
            yield b"".join((carry, memoryview(data)[:cut])) if carry or cut < len(data) else data
            offset += len(carry) + cut
            carry = data[cut:]
        data = f.read(BLOCK_BYTES)
    if carry:
        yield carry


def _strip_newline(raw: bytes) -> bytes:
    raw = raw.removesuffix(b"\n")
    return raw.removesuffix(b"\r")


def _skipped(raw: bytes) -> bool:
    """A blank line or a comment."""
    text = raw.strip()
    return not text or text.startswith(b"#")


class _Cursor:
    """Lines one at a time from the blocks (for the lines before the data)."""

    def __init__(self, blocks: Iterator[bytes]) -> None:
        self.blocks = blocks
        self.block = b""
        self.pos = 0
        self.line = 1  # the number of the line at ``pos``
        self.unread_at = (0, 1)

    def next_content(self) -> tuple[int, bytes] | None:
        """(number, line without its newline) of the next line that is not skipped."""
        while True:
            if self.pos >= len(self.block):
                nxt = next(self.blocks, None)
                if nxt is None:
                    return None
                self.block, self.pos = nxt, 0
            end = self.block.find(b"\n", self.pos)
            end = len(self.block) if end < 0 else end + 1
            number, raw = self.line, self.block[self.pos : end]
            self.unread_at = (self.pos, self.line)
            self.pos, self.line = end, self.line + 1
            if not _skipped(raw):
                return number, _strip_newline(raw)

    def unread(self) -> None:
        """Step back before the line ``next_content`` returned last."""
        self.pos, self.line = self.unread_at

    def rest(self) -> Iterator[bytes]:
        """The blocks from here on (the first one what is left of the current block)."""
        yield self.block[self.pos :]
        yield from self.blocks


# --- the shape of the table, from its first lines ------------------------------------------


def _cells(text: str, delimiter: str, trailing: bool) -> list[str]:
    if trailing and text.endswith(delimiter):
        text = text[: -len(delimiter)]
    return text.split(delimiter)


def _numbers_split_by(text: str) -> str | None:
    """The delimiter that splits ``text`` into numbers only (a trailing one allowed)."""
    for delimiter in DELIMITERS:
        if delimiter in text and all(is_number(c) for c in _cells(text, delimiter, True)):
            return delimiter
    return "," if is_number(text) else None


def _likeliest_delimiter(data: str, header: str) -> str:
    """For a data line that is not all numbers: the delimiter the header is split by
    (as often as the data line, when one is), else the data line's commonest."""
    in_header = [d for d in DELIMITERS if d in header]
    for d in in_header:
        if header.rstrip(d).count(d) == data.rstrip(d).count(d):
            return d
    if in_header:
        return max(in_header, key=header.count)
    return max(DELIMITERS, key=data.count) if any(d in data for d in DELIMITERS) else ","


def _decode_header(path: Path, number: int, raw: bytes) -> str:
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        raise InputError(path, "not UTF-8 text", line=number) from None


class _CsvReader:
    def __init__(
        self,
        path: Path,
        f: BinaryIO,
        expected_columns: int | None,
        narrow: bool = False,
        wide: Sequence[str | int] = (),
    ) -> None:
        self.path = path
        self.narrow = narrow
        self.wide_names = wide
        self.wide: list[int] = []
        self.size = max(1, Path(path).stat().st_size)
        self.cursor = _Cursor(_blocks(path, f))
        self.expected = expected_columns
        self.budget = Budget(path)
        self.header: list[str] | None = None
        self.header_line: int | None = None
        self.delimiter = ","
        self.trailing = False
        self.width = 0

    def read(self) -> CsvTable:
        self._shape()
        if self.narrow:
            self.wide = [
                _column_index(self.path, self.header, self.width, c) for c in self.wide_names
            ]
        rows = _Rows(self)
        line = self.cursor.line
        for block in self.cursor.rest():
            if block:
                line = self._parse(line, block, rows)
        if rows.count == 0:
            raise InputError(self.path, "no data lines after the header")
        values, lines, wide = rows.done()
        return CsvTable(self.path, self.header, values, lines, self.header_line, wide)

    def _shape(self) -> None:
        """Header, delimiter, trailing delimiter and width, from the first lines."""
        first = self.cursor.next_content()
        if first is None:
            raise InputError(self.path, "the file is empty")
        number, raw = first
        if b"\r" in raw:
            problem = "lines end in a bare carriage return: save it with LF or CRLF line ends"
            raise InputError(self.path, problem, line=number)
        text = _decode_header(self.path, number, raw)
        delimiter = _numbers_split_by(text)
        if delimiter is None:  # a header line
            self.budget.take(len(raw) * _HEADER_CELL_BYTES // 2, "the header", line=number)
            self.header_line = number
            data = self.cursor.next_content()
            if data is None:
                raise InputError(self.path, "no data lines after the header")
            data_text = data[1].decode("latin-1")
            delimiter = _numbers_split_by(data_text) or _likeliest_delimiter(data_text, text)
            names = [c.strip() for c in text.split(delimiter)]
            if len(names) > 1 and not names[-1]:
                names.pop()  # the header's own trailing delimiter
            self.header = names
        else:
            data_text = text
        self.cursor.unread()
        self.delimiter = delimiter
        self.trailing = data_text.endswith(delimiter)
        width = len(_cells(data_text, delimiter, self.trailing))
        self.width = self.expected or (len(self.header) if self.header is not None else width)

    def _parse(self, first: int, block: bytes, rows: _Rows) -> int:
        """One block of whole lines into ``rows``; the number of the line after it.

        The first mistake is named when there is one.
        """
        buf = np.frombuffer(block, dtype=np.uint8)
        ends = np.flatnonzero(buf == _NEWLINE)
        count = ends.size + (not block.endswith(b"\n"))
        heads = buf[np.concatenate(([0], ends + 1))[:count]]
        data, lines = block, None
        if _MAYBE_SKIPPED[heads].any():  # blank lines or comments, maybe: keep the others
            kept = [(first + i, r) for i, r in enumerate(block.split(b"\n")) if not _skipped(r)]
            lines = np.fromiter((n for n, _ in kept), dtype=np.int64, count=len(kept))
            data = b"".join(r + b"\n" for _, r in kept)
            count = len(kept)
        if count:
            if self.trailing:
                d = self.delimiter.encode()
                data = data.replace(d + b"\r\n", b"\r\n").replace(d + b"\n", b"\n")
                data = data.removesuffix(d)
            values = _c_parse(data, self.delimiter)
            if values is None or values.shape != (count, self.width):
                raise self._first_mistake(first, block)
            if lines is None:
                lines = np.arange(first, first + count, dtype=np.int64)
            rows.add(values, lines, len(block))
        return first + ends.size

    def _first_mistake(self, first: int, block: bytes) -> InputError:
        """Walk a block the C reader refused: its first bad line and cell."""
        for i, raw in enumerate(block.split(b"\n")):
            if _skipped(raw):
                continue
            number = first + i
            text = _strip_newline(raw).decode("latin-1")
            if self.trailing and text.endswith(self.delimiter):
                text = text[: -len(self.delimiter)]
            got = text.count(self.delimiter) + 1
            if got != self.width:
                return InputError(self.path, f"{got} columns, expected {self.width}", line=number)
            for col, cell in enumerate(text.split(self.delimiter)):
                if not is_number(cell):
                    return self._not_a_number(number, col, cell)
        return InputError(self.path, "numpy cannot parse these lines", line=first)

    def _not_a_number(self, number: int, col: int, cell: str) -> InputError:
        shown = cell.strip().encode("latin-1").decode("utf-8", "replace")
        problem = f"{clip(shown)!r} is not a number" if shown else "an empty cell"
        if self.delimiter != "," and _DECIMAL_COMMA.fullmatch(shown):
            problem += " (a decimal comma: numbers want a point, 1.5)"
        column = _describe_column(self.header, col)
        return InputError(self.path, problem, line=number, column=column)


def _c_parse(data: bytes, delimiter: str) -> np.ndarray | None:
    """numpy's C reader on whole lines; None when it refuses them."""
    try:
        with warnings.catch_warnings():
            # Lines that hold no values: numpy warns and gives nothing; the line-by-line
            # check after it names the line, which is the error the user sees.
            warnings.filterwarnings("ignore", "loadtxt: input contained no data", UserWarning)
            return np.loadtxt(
                io.BytesIO(data),
                delimiter=delimiter,
                comments=None,
                quotechar=None,
                encoding="latin-1",  # any byte decodes; what is not a number fails in numpy
                ndmin=2,
                dtype=np.float64,
            )
    except ValueError:
        return None


class _Rows:
    """The table's rows as they come, in one array grown within the read's budget (and each
    wide column in one of its own)."""

    def __init__(self, reader: _CsvReader) -> None:
        self.reader = reader
        self.width = reader.width
        self.dtype = np.dtype(np.float32 if reader.narrow else np.float64)
        # The values, the line number and the wide columns.
        self.row_bytes = self.dtype.itemsize * reader.width + 8 + 8 * len(reader.wide)
        self.count = 0
        self.capacity = 0
        self.bytes_seen = 0
        self.values = np.empty((0, reader.width), dtype=self.dtype)
        self.lines = np.empty(0, dtype=np.int64)
        self.wide = {c: np.empty(0) for c in reader.wide}

    def add(self, values: np.ndarray, lines: np.ndarray, nbytes: int) -> None:
        end = self.count + values.shape[0]
        self.bytes_seen += nbytes
        if end > self.capacity:
            self._grow(end, int(lines[-1]))
        if self.reader.narrow:
            for c, column in self.wide.items():
                column[self.count : end] = values[:, c]
                np.clip(values[:, c], -FLOAT32_MAX, FLOAT32_MAX, out=values[:, c])  # kept whole
            self._check_narrow(values, lines)
        self.values[self.count : end] = values
        self.lines[self.count : end] = lines
        self.count = end

    def _check_narrow(self, values: np.ndarray, lines: np.ndarray) -> None:
        """No value past float32's range (NaN and infinities pass: they are kept)."""
        low, high = values.min(), values.max()  # NaN propagates: the full look below
        if np.isfinite(low) and np.isfinite(high) and max(-low, high) <= FLOAT32_MAX:
            return
        big = np.isfinite(values) & (np.abs(values) > FLOAT32_MAX)
        if big.any():
            row, col = np.unravel_index(int(np.argmax(big)), big.shape)
            column = _describe_column(self.reader.header, int(col))
            problem = describe_value(float(values[row, col]))
            raise InputError(self.reader.path, problem, line=int(lines[row]), column=column)

    def _grow(self, needed: int, line: int) -> None:
        # Room for the whole file at the bytes per row seen so far, or half as much again.
        whole = math.ceil(1.02 * self.reader.size * needed / max(1, self.bytes_seen))
        capacity = max(needed, math.ceil(1.5 * self.capacity), whole)
        if (capacity - self.capacity) * self.row_bytes > self.reader.budget.left:
            capacity = max(needed, min(capacity, math.ceil(1.5 * self.capacity)))
        what = f"{capacity} rows of {self.width} columns"
        self.reader.budget.take((capacity - self.capacity) * self.row_bytes, what, line=line)
        if self.capacity == 0:  # not resize: it would fill the new rows with zeros first
            self.values = np.empty((capacity, self.width), dtype=self.dtype)
            self.lines = np.empty(capacity, dtype=np.int64)
            self.wide = {c: np.empty(capacity) for c in self.wide}
        else:
            self.values.resize((capacity, self.width), refcheck=False)
            self.lines.resize(capacity, refcheck=False)
            for column in self.wide.values():
                column.resize(capacity, refcheck=False)
        self.capacity = capacity

    def done(self) -> tuple[np.ndarray, np.ndarray, dict[int, np.ndarray]]:
        self.values.resize((self.count, self.width), refcheck=False)
        self.lines.resize(self.count, refcheck=False)
        for column in self.wide.values():
            column.resize(self.count, refcheck=False)
        return self.values, self.lines, self.wide


def first_bad(values: np.ndarray) -> tuple[int, ...] | None:
    """Index of the first NaN, infinite, negative or too large value (C order), None when
    all good. Too large: past float32's range, which the frames are kept in."""
    if values.size == 0:
        return None
    low, high = values.min(), values.max()  # NaN propagates: two passes, no temporaries
    wide = values.dtype.kind == "f" and values.dtype.itemsize > 4  # others cannot be too large
    if np.isfinite(low) and np.isfinite(high) and low >= 0 and not (wide and high > FLOAT32_MAX):
        return None
    bad = ~np.isfinite(values) | (values < 0)
    if wide:
        bad |= values > FLOAT32_MAX
    if not bad.any():
        return None
    flat = int(np.argmax(bad.reshape(-1)))
    return tuple(int(i) for i in np.unravel_index(flat, values.shape))


def describe_value(value: float) -> str:
    if math.isnan(value):
        return "NaN"
    if math.isinf(value):
        return "an infinite value"
    if value > FLOAT32_MAX:
        return f"value {value:g} too large (float32 holds {FLOAT32_MAX:.3g})"
    return f"negative value {value:g}"
