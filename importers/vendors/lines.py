"""Reading a vendor's text export line by line, with bounds: line length, total bytes, gzip.

Every vendor format here is text. Files are read one line at a time (never
whole), each line capped at ``MAX_LINE_BYTES``; a gzip file (by its magic
bytes, whatever its name) is decompressed on the fly and stops at
``MAX_GZIP_RATIO`` times its own size, so a small file that inflates without
end is refused, not read. Lines are decoded as UTF-8 (a leading byte order
mark dropped) and, where that fails, as Latin-1: the vendors' Windows tools
write both, and only the header's unit names (``N/cm²``) differ between them.
"""

from __future__ import annotations

import gzip
import io
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any, BinaryIO, Final

import numpy as np
from scotti.importers.errors import InputError

MAX_LINE_BYTES: Final = 1 << 20  # no vendor line is near this (pedar: 1.6 kB)
MAX_GZIP_RATIO: Final = 64  # text of numbers compresses 3-10 x; more is not a recording
_GZIP_MAGIC: Final = b"\x1f\x8b"
_CHUNK_ROWS: Final = 4096  # rows per block while collecting values


def is_gzip(path: Path) -> bool:
    try:
        with path.open("rb") as f:
            return f.read(2) == _GZIP_MAGIC
    except OSError:
        return False


def file_size(path: Path) -> int:
    try:
        return path.stat().st_size
    except OSError as exc:
        raise InputError(path, f"cannot read ({exc.__class__.__name__})") from None


class _Capped(io.RawIOBase):
    """A gzip stream that refuses to give more than ``limit`` bytes."""

    def __init__(self, inner: gzip.GzipFile, limit: int, path: Path) -> None:
        self.inner, self.limit, self.path, self.given = inner, limit, path, 0

    def readable(self) -> bool:
        return True

    def readinto(self, buffer: memoryview) -> int:  # type: ignore[override]
        try:
            data = self.inner.read(len(buffer))
        except (OSError, EOFError, zlib.error) as exc:
            problem = f"broken gzip data ({exc.__class__.__name__})"
            raise InputError(self.path, problem) from None
        self.given += len(data)
        if self.given > self.limit:
            problem = f"inflates past {MAX_GZIP_RATIO} x its size: not a recording"
            raise InputError(self.path, problem)
        buffer[: len(data)] = data
        return len(data)


class TextLines:
    """``for number, line in TextLines(path)``: 1-based numbers, line ends stripped."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.number = 0  # the line last given
        self._raw: BinaryIO | None = None
        self._opened: list[Any] = []  # outermost last: closed in reverse

    def __enter__(self) -> TextLines:
        size = file_size(self.path)
        try:
            raw: Any = self.path.open("rb")
            self._opened.append(raw)
            if is_gzip(self.path):
                inflated = gzip.GzipFile(fileobj=raw, mode="rb")
                self._opened.append(inflated)
                limit = MAX_GZIP_RATIO * size + (1 << 20)
                raw = io.BufferedReader(_Capped(inflated, limit, self.path))
                self._opened.append(raw)
        except OSError as exc:
            self.__exit__()
            raise InputError(self.path, f"cannot read ({exc.__class__.__name__})") from None
        self._raw = raw
        return self

    def __exit__(self, *exc: object) -> None:
        for stream in reversed(self._opened):
            stream.close()
        self._opened.clear()

    def __iter__(self) -> Iterator[tuple[int, str]]:
        assert self._raw is not None, "use TextLines in a with block"
        while True:
            try:
                data = self._raw.readline(MAX_LINE_BYTES + 1)
            except OSError as exc:
                raise InputError(self.path, f"cannot read ({exc.__class__.__name__})") from None
            if not data:
                return
            self.number += 1
            if len(data) > MAX_LINE_BYTES and not data.endswith(b"\n"):
                problem = f"line longer than {MAX_LINE_BYTES} bytes: not this format"
                raise InputError(self.path, problem, line=self.number)
            yield self.number, decode(data).rstrip("\r\n")

    def fail(self, problem: str, column: int | str | None = None) -> InputError:
        """An error at the line last given."""
        return InputError(self.path, problem, line=self.number, column=column)


def decode(data: bytes) -> str:
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return data.decode("latin-1")


def head_text(path: Path, limit: int = 16384) -> str:
    """The first ``limit`` bytes of a file's text (gzip inflated), for detection."""
    try:
        with path.open("rb") as raw:
            if raw.read(2) == _GZIP_MAGIC:
                raw.seek(0)
                with gzip.GzipFile(fileobj=raw, mode="rb") as inflated:
                    data = inflated.read(limit)
            else:
                raw.seek(0)
                data = raw.read(limit)
    except (OSError, EOFError, zlib.error) as exc:
        raise InputError(path, f"cannot read ({exc.__class__.__name__})") from None
    return decode(data)


class Rows:
    """Rows of numbers collected in blocks: memory grows with the data, never ahead of it."""

    def __init__(self, width: int, dtype: type[np.floating[Any]] = np.float32) -> None:
        self.width, self.dtype = width, dtype
        self._blocks: list[np.ndarray] = []
        self._block = np.empty((_CHUNK_ROWS, width), dtype=dtype)
        self._fill = 0

    def add(self, row: np.ndarray) -> None:
        if self._fill == _CHUNK_ROWS:
            self._blocks.append(self._block)
            self._block = np.empty((_CHUNK_ROWS, self.width), dtype=self.dtype)
            self._fill = 0
        self._block[self._fill] = row
        self._fill += 1

    def __len__(self) -> int:
        return len(self._blocks) * _CHUNK_ROWS + self._fill

    def array(self) -> np.ndarray:
        """(n, width) of every row added."""
        return np.concatenate([*self._blocks, self._block[: self._fill]], axis=0)
