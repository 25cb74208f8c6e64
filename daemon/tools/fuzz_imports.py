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
import struct
import traceback
import zipfile
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any, Final

import numpy as np
from scotti.daemon.tools.fuzz_inputs import mutate as mutate_bytes

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
_HOSTILE_CELLS: Final = (
    "nan", "NaN", "inf", "-inf", "-1", "-0", "1e309", "-1e309", "", " ", "x", "1,5", "0x10",
    "1_0", "+.5", "5.", "1e", "--1", "\u0661", "\ufeff1", "9" * 400, "1" + "0" * 5000, "\x00",
    "\t", "#", "1;2", '"1"', "1e-400", "4.9e-324", "1.7976931348623157e308",
)  # fmt: skip
_HOSTILE_BYTES: Final = (b"\xff\xfe", b"\xc3", b"\x80", b"\r", b"\r\r\n", b"\x1a", b"\xef\xbb\xbf")


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


# --- byte-level edits ----------------------------------------------------------------------


def mutate(rnd: random.Random, seed: bytes, edits: int = 8) -> bytes:
    """``seed`` with 1-``edits`` edits (fuzz_inputs.mutate), the text formats' hostile
    bytes among the values and inserts."""
    return mutate_bytes(rnd, seed, edits, (0x00, 0xFF, 0x0A, 0x2C), _HOSTILE_BYTES)


def _numbers(rnd: random.Random, shape: tuple[int, ...]) -> np.ndarray:
    return np.random.default_rng(rnd.getrandbits(32)).uniform(0, 200, shape)


# --- csv -----------------------------------------------------------------------------------


def _csv_table(rnd: random.Random, rows: int, cols: int) -> bytes:
    """A valid pressure CSV for the grid, in one of the ways people write them."""
    frames = rnd.randint(1, 40)
    times = rnd.uniform(-5, 5) + np.arange(frames) / rnd.choice((16.0, 100.0, 50.5, 1e3))
    body = np.column_stack([times, _numbers(rnd, (frames, 2 * rows * cols))])
    d = rnd.choice((",", ",", "\t", ";"))
    fmt = rnd.choice(("{:.3f}", "{:g}", "{:.6e}", "{:.0f}", "{!r}"))
    end = d if rnd.random() < 0.15 else ""
    lines = [d.join(fmt.format(float(v)) for v in row) + end for row in body]
    if rnd.random() < 0.5:
        names = ["t"] + [f"{f}{i}" for f in "LR" for i in range(rows * cols)]
        lines.insert(0, d.join(names) + end)
    for _ in range(rnd.choice((0, 0, 1, 3))):
        lines.insert(rnd.randint(0, len(lines)), rnd.choice(("# a comment", "", "  ", "#")))
    newline = "\r\n" if rnd.random() < 0.2 else "\n"
    text = newline.join(lines) + (newline if rnd.random() < 0.9 else "")
    return (b"\xef\xbb\xbf" if rnd.random() < 0.05 else b"") + text.encode()


def _edit_cells(rnd: random.Random, text: bytes) -> bytes:
    """Some cells of some lines replaced by hostile ones; a line made wider or narrower."""
    lines = text.split(b"\n")
    for _ in range(rnd.randint(1, 4)):
        i = rnd.randrange(len(lines))
        cells = lines[i].split(b",")
        j = rnd.randrange(len(cells))
        kind = rnd.randrange(4)
        if kind == 0:
            cells[j] = rnd.choice(_HOSTILE_CELLS).encode()
        elif kind == 1:
            cells[j] = rnd.choice(_HOSTILE_BYTES)
        elif kind == 2:
            cells.insert(j, b"1")
        elif len(cells) > 1:
            del cells[j]
        lines[i] = b",".join(cells)
    return b"\n".join(lines)


def make_csv(rnd: random.Random, seeds: Seeds) -> ImportCase:
    rows, cols = rnd.randint(1, 4), rnd.randint(1, 3)
    table = _csv_table(rnd, rows, cols)
    kind = rnd.randrange(10)
    if kind <= 2:
        data, how = table, "valid"
    elif kind <= 4:
        data, how = mutate(rnd, table), "mutated"
    elif kind <= 6:
        data, how = _edit_cells(rnd, table), "hostile cells"
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


# --- npz -----------------------------------------------------------------------------------

_DTYPES: Final = ("<f8", "<f4", "<f2", ">f8", "<i4", "|u1", "|b1", "<c16", "<U3", "|S2", "|O")


def _array(rnd: random.Random, shape: tuple[int, ...]) -> np.ndarray:
    values = _numbers(rnd, shape)
    if rnd.random() < 0.1 and values.size:
        values.flat[rnd.randrange(values.size)] = rnd.choice((np.nan, np.inf, -1.0, 1e300))
    dtype = rnd.choice(_DTYPES) if rnd.random() < 0.2 else "<f8"
    if dtype == "|O":
        return np.array([{"a": 1}] * max(1, values.size), dtype=object)
    with np.errstate(all="ignore"):  # 1e300 as float16 is meant to be inf here
        array = values.astype(dtype)
    return np.asfortranarray(array) if rnd.random() < 0.1 else array


def _npz_arrays(rnd: random.Random, rows: int, cols: int) -> dict[str, np.ndarray]:
    frames = rnd.randint(1, 30)
    times = rnd.uniform(-5, 5) + np.arange(frames) / 100.0
    if rnd.random() < 0.1:
        times = times[::-1].copy()
    shape: tuple[int, ...] = (frames, rows, cols) if rnd.random() < 0.8 else (frames, rows * cols)
    if rnd.random() < 0.1:
        shape = tuple(max(0, n + rnd.choice((-1, 1))) for n in shape)
    arrays = {"time": times, "left": _array(rnd, shape), "right": _array(rnd, shape)}
    if rnd.random() < 0.1:
        del arrays[rnd.choice(list(arrays))]
    return arrays


def _npz_bytes(arrays: dict[str, np.ndarray], compressed: bool) -> bytes:
    """As ``np.savez`` (or ``savez_compressed``) writes them."""
    buffer = io.BytesIO()
    how = zipfile.ZIP_DEFLATED if compressed else zipfile.ZIP_STORED
    with zipfile.ZipFile(buffer, "w", how) as z:
        for name, array in arrays.items():
            z.writestr(f"{name}.npy", _npy(array))
    return buffer.getvalue()


def _lying_member(rnd: random.Random, rows: int, cols: int) -> bytes:
    """An npz whose ``left`` header declares what its bytes are not."""
    shape = rnd.choice(
        (
            (10**9, rows, cols),
            (2**62, 2**62),
            (rnd.randint(1, 30), rows, cols),
            (-1, rows),
            (),
            (0, rows, cols),
        )
    )
    descr: Any = rnd.choice(("<f8", "|O", "<V8", "<M8[ns]", "|S0", [("a", "<f8")], "<f8"))
    header = {"descr": descr, "fortran_order": rnd.choice((False, True)), "shape": shape}
    member = io.BytesIO()
    np.lib.format.write_array_header_1_0(member, header)
    data = member.getvalue() + rnd.randbytes(rnd.choice((0, 8, 96, 4096)))
    if rnd.random() < 0.3:
        data = data.replace(b"'descr'", rnd.choice((b"'desc'", b"'descr' ", b"'descr'")))
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", rnd.choice((zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED))) as z:
        z.writestr("time.npy", _npy(np.arange(10) / 10.0))
        z.writestr("left.npy", data)
        z.writestr("right.npy", _npy(np.zeros((10, rows, cols))))
    return buffer.getvalue()


def _npy(array: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, array)
    return buffer.getvalue()


def _lie_in_directory(rnd: random.Random, data: bytes) -> bytes:
    """One size or offset in a local or central zip header set to something else."""
    out = bytearray(data)
    marks = [(b"PK\x03\x04", (18, 22)), (b"PK\x01\x02", (20, 24, 42))]
    mark, offsets = rnd.choice(marks)
    places: list[int] = []
    at = out.find(mark)
    while at >= 0:
        places.append(at)
        at = out.find(mark, at + 1)
    if places:
        at = rnd.choice(places) + rnd.choice(offsets)
        value = rnd.choice((0, 1, 0xFFFFFFFF, 0x7FFFFFFF, rnd.randrange(2**32)))
        out[at : at + 4] = struct.pack("<I", value)
    return bytes(out)


def make_npz(rnd: random.Random, seeds: Seeds) -> ImportCase:
    rows, cols = rnd.randint(1, 4), rnd.randint(1, 3)
    valid = _npz_bytes(_npz_arrays(rnd, rows, cols), compressed=rnd.random() < 0.5)
    kind = rnd.randrange(10)
    if kind <= 2:
        data, how = valid, "valid"
    elif kind <= 4:
        data, how = mutate(rnd, valid), "mutated"
    elif kind <= 6:
        data, how = _lying_member(rnd, rows, cols), "a header that lies"
    elif kind == 7:
        data, how = _lie_in_directory(rnd, valid), "a zip directory that lies"
    elif kind == 8:
        bomb = seeds.npz_bomb()
        data, how = (bomb if rnd.random() < 0.5 else _lie_in_directory(rnd, bomb)), "a bomb"
    else:
        data, how = b"PK\x03\x04" + rnd.randbytes(rnd.randint(0, 2048)), "garbage"
    return ImportCase("npz", ".npz", data, rows, cols, how)


# --- h5 ------------------------------------------------------------------------------------


def _h5_bytes(rnd: random.Random, rows: int, cols: int) -> tuple[bytes, str]:
    """An HDF5 file made by h5py: valid, or with datasets hostile in one way."""
    import h5py

    frames = rnd.randint(1, 30)
    buffer = io.BytesIO()
    how = "valid"
    with h5py.File(buffer, "w") as f:
        f["time"] = rnd.uniform(-5, 5) + np.arange(frames) / 100.0
        for name in ("left", "right"):
            f[name] = _numbers(rnd, (frames, rows, cols))
        victim = rnd.choice(("time", "left", "right"))
        kind = rnd.randrange(12)
        if kind >= 4:
            del f[victim]
        if kind == 4:
            how = "declared, never written"
            chunks = rnd.choice((None, True))
            shape: tuple[int, ...] = (rnd.choice((10**9, 10**6, frames)),)
            if victim != "time":
                shape = (shape[0], rows, cols)
            f.create_dataset(victim, shape=shape, dtype="f8", chunks=chunks)
        elif kind == 5:
            how = "compressed, never written"
            f.create_dataset(victim, shape=(10**9,), dtype="f8", chunks=(10**5,), compression=9)
        elif kind == 6:
            how = "not numbers"
            choice = rnd.randrange(4)
            if choice == 0:
                f[victim] = ["a", "b"]
            elif choice == 1:
                f[victim] = np.zeros(3, dtype=[("a", "<f8"), ("b", "<i4")])
            elif choice == 2:
                f[victim] = np.ones(3, dtype=complex)
            else:
                f[victim] = h5py.Empty("f8")
        elif kind == 7:
            how = "a link to nowhere"
            if rnd.random() < 0.5:
                f[victim] = h5py.SoftLink("/nowhere")
            else:
                f[victim] = h5py.ExternalLink("missing.h5", "/t")
        elif kind == 8:
            how = "a group"
            f.create_group(victim)
        elif kind == 9:
            how = "filtered"
            data = _numbers(rnd, (frames,) if victim == "time" else (frames, rows, cols))
            f.create_dataset(
                victim, data=data, chunks=True, shuffle=True, fletcher32=True, compression="gzip"
            )
        elif kind == 10:
            how = "scalar"
            f[victim] = 1.0
        elif kind == 11:
            how = "other shape"
            f[victim] = _numbers(rnd, tuple(rnd.randint(0, 4) for _ in range(rnd.randint(0, 4))))
    return buffer.getvalue(), how


def make_h5(rnd: random.Random, seeds: Seeds) -> ImportCase:
    rows, cols = rnd.randint(1, 4), rnd.randint(1, 3)
    data, how = _h5_bytes(rnd, rows, cols)
    kind = rnd.randrange(10)
    if kind == 0:
        data, how = data[: rnd.randrange(len(data))], f"{how}, cut"
    elif kind == 1:
        data, how = mutate(rnd, data, edits=2), f"{how}, mutated"
    elif kind == 2:
        data, how = b"\x89HDF\r\n\x1a\n" + rnd.randbytes(rnd.randint(0, 2048)), "garbage"
    return ImportCase("h5", ".h5", data, rows, cols, how)


# --- vendor --------------------------------------------------------------------------------


def _edit_lines(rnd: random.Random, text: bytes) -> bytes:
    """Lines repeated, dropped or made very long; numbers made hostile."""
    lines = text.split(b"\n")
    for _ in range(rnd.randint(1, 4)):
        i = rnd.randrange(len(lines))
        kind = rnd.randrange(5)
        if kind == 0:
            lines.insert(i, lines[rnd.randrange(len(lines))])
        elif kind == 1 and len(lines) > 1:
            del lines[i]
        elif kind == 2:
            lines[i] += b"1\t" * rnd.choice((1000, 600_000))
        else:
            cells = lines[i].split(b"\t") if b"\t" in lines[i] else lines[i].split(b",")
            j = rnd.randrange(len(cells))
            cells[j] = rnd.choice(_HOSTILE_CELLS).encode("utf-8", "replace")
            lines[i] = (b"\t" if b"\t" in lines[i] else b",").join(cells)
    return b"\n".join(lines)


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
        data, how = _edit_lines(rnd, text), "edited lines"
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
