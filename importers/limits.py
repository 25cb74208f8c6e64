"""How much memory one read may allocate, checked before anything is allocated.

A file's declared sizes (an HDF5 dataset's shape, an ``.npz`` member's
header) are promises; what a reader allocates for them is checked first
against the file's own bytes (in ``tables``) and then against this budget,
so a 2 kB file that declares 10^9 samples, or a 1 MB ``.npz`` that inflates
to a gigabyte, is one line and exit 2 instead of a MemoryError.

The budget of one read is the least of:

- 100 times the file's size (but at least 256 MB): numbers unpack to a few
  times their text, and recorded data compress a few times, not a thousand
  (deflate's most, reached by a file of zeros);
- half of the machine's memory;
- a third of the address space left under a limit (``ulimit -v``): the
  import holds about three times what it reads (the values, the frames in
  float32, the counts and the temporaries of resampling).

``SCOTTI_IMPORT_MAX_BYTES`` sets it outright, for a file that is what it
says it is.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Final

from scotti.importers.errors import ImporterError, InputError

ENV_VAR: Final = "SCOTTI_IMPORT_MAX_BYTES"
SHARE_OF_MEMORY: Final = 0.5
TIMES_FILE_SIZE: Final = 100
FLOOR_BYTES: Final = 256_000_000
COPIES_HELD: Final = 3  # what the import holds per byte read (see above)
_UNITS: Final = {"": 1, "k": 2**10, "m": 2**20, "g": 2**30, "t": 2**40}


def size_text(nbytes: int | float) -> str:
    """Bytes for people: 1.07 GB, 980 kB, 12 bytes (decimal units)."""
    for unit, scale in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if nbytes >= scale:
            return f"{nbytes / scale:.3g} {unit}"
    return f"{int(nbytes)} bytes"


def _from_env(text: str) -> int:
    match = re.fullmatch(r"\s*(\d+(?:\.\d+)?)\s*([kmgt]?)i?b?\s*", text.lower())
    if match is None:
        msg = f"{ENV_VAR}={text[:40]!r}: want a size in bytes, e.g. 2000000000 or 2G"
        raise ImporterError(msg)
    return int(float(match[1]) * _UNITS[match[2]])


def _address_space_left() -> int | None:
    """Bytes of address space this process may still map, None without a limit."""
    try:
        import resource  # POSIX only
    except ModuleNotFoundError:  # pragma: no cover - Windows
        return None
    soft = min(
        (
            limit
            for limit in (
                resource.getrlimit(resource.RLIMIT_AS)[0],
                resource.getrlimit(resource.RLIMIT_DATA)[0],
            )
            if limit != resource.RLIM_INFINITY
        ),
        default=None,
    )
    if soft is None:
        return None
    try:
        status = Path("/proc/self/status").read_text()
    except OSError:  # no procfs: count the whole limit as left
        status = ""
    used = re.search(r"VmSize:\s*(\d+) kB", status)
    return max(0, soft - (int(used[1]) * 1024 if used else 0))


def budget(file_bytes: int) -> tuple[int, str]:
    """(bytes one read of a file of ``file_bytes`` may allocate, what that figure is)."""
    env = os.environ.get(ENV_VAR, "").strip()
    if env:
        return _from_env(env), f"{ENV_VAR} allows"
    try:
        memory = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, ValueError, OSError):  # pragma: no cover - no sysconf
        memory = 2**33
    options = [
        (
            max(FLOOR_BYTES, TIMES_FILE_SIZE * file_bytes),
            f"a file of {size_text(file_bytes)} may unpack to",
        ),
        (int(memory * SHARE_OF_MEMORY), "half of this machine's memory"),
    ]
    left = _address_space_left()
    if left is not None:
        options.append((left // COPIES_HELD, "a third of the memory left under ulimit"))
    return min(options)


class Budget:
    """What is left of one read's budget; ``take`` refuses what would not fit."""

    def __init__(self, path: str | os.PathLike[str], total: int | None = None) -> None:
        self.path = path
        if total is None:
            try:
                file_bytes = os.stat(path).st_size
            except OSError:
                file_bytes = 0
            self.total, self.limit = budget(file_bytes)
        else:
            self.total, self.limit = total, "this read may take"
        self.left = self.total

    def take(
        self, nbytes: int, what: str, *, line: int | None = None, column: str | None = None
    ) -> None:
        """Count ``nbytes`` against the budget, or an InputError saying it does not fit."""
        if nbytes > self.left:
            figure = size_text(self.total)
            if size_text(self.left) != figure:
                figure = f"{size_text(self.left)} left of {figure}"
            problem = f"{what} needs {size_text(nbytes)}, more than {self.limit} ({figure})"
            if not self.limit.startswith(ENV_VAR):
                problem += f"; {ENV_VAR} raises it"
            raise InputError(self.path, problem, line=line, column=column)
        self.left -= nbytes

    def give_back(self, nbytes: int) -> None:
        self.left = min(self.total, self.left + nbytes)
