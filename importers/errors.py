"""Errors of the importers: one root, one-line messages that say where.

A user's file that cannot be imported is an ``InputError`` naming the file,
and where the format has them the line and the column (CSV), or the array
and the index (``.npz``, HDF5), so the mistake can be found and fixed.
Every message is one line (``scotti import`` prints it and exits 2), and
text quoted from a file is clipped: a bad 2 kB row is named, not echoed.
"""

from __future__ import annotations

import os
from typing import Final

QUOTE_CHARS: Final = 80  # the most of a file's own text an error message echoes


def clip(text: str, limit: int = QUOTE_CHARS) -> str:
    """``text`` cut to ``limit`` characters (an ellipsis says it was cut)."""
    return text if len(text) <= limit else text[: limit - 3] + "..."


def one_line(text: str) -> str:
    """``text`` with line breaks and other control characters made spaces."""
    return "".join(" " if not ch.isprintable() else ch for ch in text)


class ImporterError(Exception):
    """Root of every error raised by ``scotti.importers`` (one line, exit 2)."""

    def __init__(self, message: str) -> None:
        super().__init__(one_line(message))


class InputError(ImporterError):
    """A recording, a segment file or a configuration that cannot be imported."""

    def __init__(
        self,
        file: str | os.PathLike[str],
        problem: str,
        *,
        line: int | None = None,
        column: int | str | None = None,
    ) -> None:
        self.file = str(file)
        self.line = line
        self.column = column
        where = self.file
        if line is not None:
            where += f" line {line}"
        if column is not None:
            where += f", column {column}" if line is not None else f" {column}"
        super().__init__(f"{where}: {problem}")
        self.problem = problem
