"""The import readers' fuzz inputs, and the check each input must pass, in a worker process.

Targets: ``csv``, ``npz`` and ``h5`` (a pressure table through ``scotti
import``'s whole path, ``format = "table"`` with a grid drawn for it) and
``vendor`` (a vendor export, its format detected). Inputs are valid files
made hostile: bytes cut, flipped, inserted or repeated; cells made NaN,
infinite, negative, empty, enormous or not UTF-8; lines a megabyte and more
long; headers that declare shapes of 10^9 and more, dtypes that are not
numbers, zip directories that lie, compressed members of zeros that inflate
to hundreds of megabytes, HDF5 datasets never written, links that lead
nowhere; binary garbage. Vendor inputs start from the head of each sample
in ``../shared/realdata`` (garbage only, without it).

The check: the import ends cleanly, or with an ``ImporterError`` of one
line that quotes little and is no out-of-memory (the readers' budget must
refuse before the allocator does). Anything else is a finding. Each input
runs in a worker process under an address-space limit (``WORKER_MEMORY``),
so a reader that allocates without bound fails there, and a crash in a C
library (libhdf5 on a corrupt file) or a hang (``WORKER_TIMEOUT_S``) is a
finding, not the end of the run.
"""

from __future__ import annotations

import atexit
import gzip
import io
import multiprocessing
import os
import random
import traceback
import zipfile
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any, Final

import numpy as np
from scotti.daemon.tools.fuzz_import_formats import (
    csv_table,
    edit_cells,
    edit_lines,
    h5_bytes,
    lie_in_directory,
    lying_member,
    mutate,
    npz_arrays,
    npz_bytes,
)

IMPORT_TARGETS: Final = ("csv", "npz", "h5", "vendor")
WORKER_MEMORY: Final = 2 << 30  # address space of the worker, bytes
WORKER_TIMEOUT_S: Final = 60.0  # one input's import, at most
MESSAGE_CHARS: Final = 400  # an error's length past its file's name, at most
REALDATA: Final = Path(__file__).resolve().parents[2].parent / "shared" / "realdata"
# One sample per vendor format (the head of it seeds the inputs).
VENDOR_SEEDS: Final = (
    "pressure-r/pedar_example.asc",
    "pressure-r/fscan_testL.asf",
    "pressure-r/xsensor_data.csv",
    "moticon-opengo/230927_102137.txt",
    "physionet-gaitpdb/GaCo01_01.txt.gz",
)
_SEED_BYTES: Final = 48_000  # of each vendor sample: its header and some frames
_BOMB_BYTES: Final = 320_000_000  # zeros in the compressed seeds: past the 256 MB floor


class FindingError(Exception):
    """What an input did that it must not, already described (``Type at file:line: ...``)."""


@dataclass(frozen=True)
class ImportCase:
    """One input: a file's bytes, its suffix and, for tables, the grid the import declares."""

    target: str
    suffix: str
    data: bytes
    rows: int = 1
    cols: int = 1
    how: str = ""  # how it was made, for the finding's report

    def __repr__(self) -> str:
        head = self.data[:160]
        return (
            f"ImportCase({self.target}{self.suffix}, {self.how}, {len(self.data)} bytes, "
            f"grid {self.rows}x{self.cols}, starts {head!r})"
        )


# --- the seeds: built once a run ---------------------------------------------------------


@dataclass
class Seeds:
    """What inputs are made from: vendor heads, and the costly compressed bombs."""

    workdir: Path
    realdata: Path = REALDATA
    vendor: list[tuple[str, bytes, bool]] = field(default_factory=list)  # (suffix, text, gz)
    _npz_bomb: bytes | None = None
    _gzip_bomb: bytes | None = None

    def __post_init__(self) -> None:
        for relative in VENDOR_SEEDS:
            path = self.realdata / relative
            if not path.is_file():
                continue
            zipped = path.suffix == ".gz"
            with gzip.open(path, "rb") if zipped else path.open("rb") as f:
                text = f.read(_SEED_BYTES)
            text = text[: text.rfind(b"\n") + 1] or text
            suffix = "".join(path.suffixes[-2:]) if zipped else path.suffix
            self.vendor.append((suffix, text, zipped))

    def npz_bomb(self) -> bytes:
        """A member ``left`` of 320 MB of zeros, deflated to about 300 kB."""
        if self._npz_bomb is None:
            buffer = io.BytesIO()
            with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as z:
                with z.open("time.npy", "w") as f:
                    np.lib.format.write_array(f, np.arange(10) / 10.0)
                with z.open("left.npy", "w", force_zip64=True) as f:
                    count = _BOMB_BYTES // 8
                    header = {"descr": "<f8", "fortran_order": False, "shape": (count,)}
                    np.lib.format.write_array_header_1_0(f, header)
                    block = bytes(1 << 22)
                    for start in range(0, count * 8, len(block)):
                        f.write(block[: min(len(block), count * 8 - start)])
            self._npz_bomb = buffer.getvalue()
        return self._npz_bomb

    def gzip_bomb(self) -> bytes:
        """320 MB of one line of zeros, gzipped."""
        if self._gzip_bomb is None:
            buffer = io.BytesIO()
            with gzip.GzipFile(fileobj=buffer, mode="wb") as f:
                block = b"0" * (1 << 22)
                for _ in range(_BOMB_BYTES // len(block)):
                    f.write(block)
            self._gzip_bomb = buffer.getvalue()
        return self._gzip_bomb


def make_csv(rnd: random.Random, seeds: Seeds) -> ImportCase:
    rows, cols = rnd.randint(1, 4), rnd.randint(1, 3)
    table = csv_table(rnd, rows, cols)
    kind = rnd.randrange(10)
    if kind <= 2:
        data, how = table, "valid"
    elif kind <= 4:
        data, how = mutate(rnd, table), "mutated"
    elif kind <= 6:
        data, how = edit_cells(rnd, table), "hostile cells"
    elif kind == 7:
        size = rnd.choice((100_000, 1_100_000, 5_000_000))  # past the reader's line bound
        data, how = table[:200] + b"1" * size + b"\n" + table[200:], f"a {size}-byte line"
    elif kind == 8:
        width = rnd.choice((10_000, 200_000))
        data, how = (b"0," * width + b"0\n") * rnd.randint(1, 3), f"{width + 1} columns"
    else:
        data, how = rnd.randbytes(rnd.randint(0, 4096)), "garbage"
    if rnd.random() < 0.1:  # the grid declared not the one written
        rows, cols = rnd.randint(1, 5), rnd.randint(1, 5)
    return ImportCase("csv", ".csv", data, rows, cols, how)


def make_npz(rnd: random.Random, seeds: Seeds) -> ImportCase:
    rows, cols = rnd.randint(1, 4), rnd.randint(1, 3)
    valid = npz_bytes(npz_arrays(rnd, rows, cols), compressed=rnd.random() < 0.5)
    kind = rnd.randrange(10)
    if kind <= 2:
        data, how = valid, "valid"
    elif kind <= 4:
        data, how = mutate(rnd, valid), "mutated"
    elif kind <= 6:
        data, how = lying_member(rnd, rows, cols), "a header that lies"
    elif kind == 7:
        data, how = lie_in_directory(rnd, valid), "a zip directory that lies"
    elif kind == 8:
        bomb = seeds.npz_bomb()
        data, how = (bomb if rnd.random() < 0.5 else lie_in_directory(rnd, bomb)), "a bomb"
    else:
        data, how = b"PK\x03\x04" + rnd.randbytes(rnd.randint(0, 2048)), "garbage"
    return ImportCase("npz", ".npz", data, rows, cols, how)


def make_h5(rnd: random.Random, seeds: Seeds) -> ImportCase:
    rows, cols = rnd.randint(1, 4), rnd.randint(1, 3)
    data, how = h5_bytes(rnd, rows, cols)
    kind = rnd.randrange(10)
    if kind == 0:
        data, how = data[: rnd.randrange(len(data))], f"{how}, cut"
    elif kind == 1:
        data, how = mutate(rnd, data, edits=2), f"{how}, mutated"
    elif kind == 2:
        data, how = b"\x89HDF\r\n\x1a\n" + rnd.randbytes(rnd.randint(0, 2048)), "garbage"
    return ImportCase("h5", ".h5", data, rows, cols, how)


def make_vendor(rnd: random.Random, seeds: Seeds) -> ImportCase:
    if not seeds.vendor:
        suffix = rnd.choice((".asc", ".asf", ".csv", ".txt", ".txt.gz"))
        return ImportCase("vendor", suffix, rnd.randbytes(rnd.randint(0, 4096)), how="garbage")
    suffix, text, zipped = rnd.choice(seeds.vendor)
    kind = rnd.randrange(10)
    if kind <= 1:
        data, how = text, "a sample's head"
    elif kind <= 4:
        data, how = mutate(rnd, text), "mutated"
    elif kind <= 8:
        data, how = edit_lines(rnd, text), "edited lines"
    else:
        data, how = rnd.randbytes(rnd.randint(0, 4096)), "garbage"
    if zipped or rnd.random() < 0.05:
        data = gzip.compress(data, mtime=0)
        if rnd.random() < 0.2:
            data, how = data[: rnd.randrange(max(1, len(data)))], f"{how}, gzip cut"
        elif rnd.random() < 0.05:
            data, how = seeds.gzip_bomb(), "a gzip bomb"
    return ImportCase("vendor", suffix, data, how=how)


MAKERS: Final = {"csv": make_csv, "npz": make_npz, "h5": make_h5, "vendor": make_vendor}


# --- the check -----------------------------------------------------------------------------


def describe(exc: BaseException) -> str:
    """``Type at file:line: message`` of where an exception was raised."""
    frames = traceback.extract_tb(exc.__traceback__)
    last = frames[-1] if frames else None
    place = f" at {Path(last.filename).name}:{last.lineno}" if last else ""
    return f"{type(exc).__name__}{place}: {str(exc)[:120]}"


def check_import(case: ImportCase, workdir: Path) -> None:
    """A clean import, or one ImporterError line; raises AssertionError on anything else."""
    from scotti.importers.config import config_from_dict
    from scotti.importers.errors import ImporterError
    from scotti.importers.run import import_recording

    path = workdir / f"fuzzed{case.suffix}"
    path.write_bytes(case.data)
    pressure: dict[str, Any] = {"file": str(path)}
    raw: dict[str, Any] = {"pressure": pressure, "source_every_s": 1.0}
    if case.target != "vendor":
        pressure |= {"format": "table", "rows": case.rows, "cols": case.cols}
        raw["counts"] = {"method": "counts", "gain": 1.0}
    try:
        cfg = config_from_dict(raw, name="fuzz")
        import_recording(cfg, workdir / "out.scotti", overwrite=True)
    except ImporterError as exc:
        message = str(exc)
    else:
        return
    assert "\n" not in message, "an error of more than one line"
    assert len(message) <= len(str(path)) + MESSAGE_CHARS, f"an error {len(message)} long"
    assert "out of memory" not in message, "the allocator refused before the budget did"


def _worker(conn: Connection, workdir: str, memory: int) -> None:
    """Runs in the worker process: checks inputs as they come, answers with findings."""
    import resource
    import warnings

    resource.setrlimit(resource.RLIMIT_AS, (memory, memory))
    warnings.simplefilter("error")  # as the test suite has it: a warning is a finding
    folder = Path(workdir)
    while True:
        try:
            case = conn.recv()
        except EOFError:
            return
        try:
            check_import(case, folder)
        except KeyboardInterrupt:
            return
        except BaseException as exc:  # every other kind is a finding; the worker goes on
            conn.send(describe(exc))
        else:
            conn.send(None)


class IsolatedCheck:
    """``check(case)`` in a worker process; raises ``FindingError`` for what must not happen."""

    def __init__(self, workdir: Path, memory: int = WORKER_MEMORY) -> None:
        self.workdir = workdir
        self.memory = memory
        self.process: Any = None
        self.conn: Connection | None = None
        atexit.register(self.close)

    def _start(self) -> Connection:
        for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
            os.environ.setdefault(var, "1")  # one thread: less address space per worker
        context = multiprocessing.get_context("spawn")
        ours, theirs = context.Pipe()
        self.workdir.mkdir(parents=True, exist_ok=True)
        self.process = context.Process(
            target=_worker, args=(theirs, str(self.workdir), self.memory), daemon=True
        )
        self.process.start()
        theirs.close()
        self.conn = ours
        return ours

    def __call__(self, case: ImportCase) -> None:
        conn = self.conn or self._start()
        conn.send(case)
        if not conn.poll(WORKER_TIMEOUT_S):
            self.close()
            raise FindingError(f"Hang: no answer in {WORKER_TIMEOUT_S:.0f} s")
        try:
            answer = conn.recv()
        except EOFError:
            code = self.process.exitcode if self.process is not None else None
            self.close()
            raise FindingError(f"Crash: the worker died (exit code {code})") from None
        if answer is not None:
            raise FindingError(answer)

    def close(self) -> None:
        if self.conn is not None:
            self.conn.close()
            self.conn = None
        if self.process is not None:
            self.process.join(timeout=5)
            if self.process.is_alive():
                self.process.kill()
                self.process.join()
            self.process = None
