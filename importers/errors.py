"""Errors of the importers: one root, one-line messages that say where.

A user's file that cannot be imported is an ``InputError`` naming the file,
and where the format has them the line and the column (CSV), or the array
and the index (``.npz``, HDF5), so the mistake can be found and fixed.
"""

from __future__ import annotations

import os


class ImporterError(Exception):
    """Root of every error raised by ``scotti.importers`` (one line, exit 2)."""


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
