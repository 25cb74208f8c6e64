"""The import fuzzer's file contents: each format's valid file, and the edits making it hostile.

Per format: a pressure CSV written in one of the ways people write them, and
its cells made hostile; an npz as ``np.savez`` writes it, one whose header lies
about its member, one whose zip directory lies; an HDF5 file made by h5py with
one dataset hostile; a vendor text's lines repeated, dropped or made very long.
Which of them an input is, ``fuzz_imports`` draws.
"""

from __future__ import annotations

import io
import random
import struct
import zipfile
from typing import Any, Final

import numpy as np
from scotti.daemon.tools.fuzz_inputs import mutate as mutate_bytes

_HOSTILE_CELLS: Final = (
    "nan", "NaN", "inf", "-inf", "-1", "-0", "1e309", "-1e309", "", " ", "x", "1,5", "0x10",
    "1_0", "+.5", "5.", "1e", "--1", "\u0661", "\ufeff1", "9" * 400, "1" + "0" * 5000, "\x00",
    "\t", "#", "1;2", '"1"', "1e-400", "4.9e-324", "1.7976931348623157e308",
)  # fmt: skip
_HOSTILE_BYTES: Final = (b"\xff\xfe", b"\xc3", b"\x80", b"\r", b"\r\r\n", b"\x1a", b"\xef\xbb\xbf")


# --- byte-level edits ----------------------------------------------------------------------


def mutate(rnd: random.Random, seed: bytes, edits: int = 8) -> bytes:
    """``seed`` with 1-``edits`` edits (fuzz_inputs.mutate), the text formats' hostile
    bytes among the values and inserts."""
    return mutate_bytes(rnd, seed, edits, (0x00, 0xFF, 0x0A, 0x2C), _HOSTILE_BYTES)


def numbers(rnd: random.Random, shape: tuple[int, ...]) -> np.ndarray:
    return np.random.default_rng(rnd.getrandbits(32)).uniform(0, 200, shape)


# --- csv ---------------------------------------------------------------------------------


def csv_table(rnd: random.Random, rows: int, cols: int) -> bytes:
    """A valid pressure CSV for the grid, in one of the ways people write them."""
    frames = rnd.randint(1, 40)
    times = rnd.uniform(-5, 5) + np.arange(frames) / rnd.choice((16.0, 100.0, 50.5, 1e3))
    body = np.column_stack([times, numbers(rnd, (frames, 2 * rows * cols))])
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


def edit_cells(rnd: random.Random, text: bytes) -> bytes:
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


# --- npz ---------------------------------------------------------------------------------

_DTYPES: Final = ("<f8", "<f4", "<f2", ">f8", "<i4", "|u1", "|b1", "<c16", "<U3", "|S2", "|O")


def _array(rnd: random.Random, shape: tuple[int, ...]) -> np.ndarray:
    values = numbers(rnd, shape)
    if rnd.random() < 0.1 and values.size:
        values.flat[rnd.randrange(values.size)] = rnd.choice((np.nan, np.inf, -1.0, 1e300))
    dtype = rnd.choice(_DTYPES) if rnd.random() < 0.2 else "<f8"
    if dtype == "|O":
        return np.array([{"a": 1}] * max(1, values.size), dtype=object)
    with np.errstate(all="ignore"):  # 1e300 as float16 is meant to be inf here
        array = values.astype(dtype)
    return np.asfortranarray(array) if rnd.random() < 0.1 else array


def npz_arrays(rnd: random.Random, rows: int, cols: int) -> dict[str, np.ndarray]:
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


def npz_bytes(arrays: dict[str, np.ndarray], compressed: bool) -> bytes:
    """As ``np.savez`` (or ``savez_compressed``) writes them."""
    buffer = io.BytesIO()
    how = zipfile.ZIP_DEFLATED if compressed else zipfile.ZIP_STORED
    with zipfile.ZipFile(buffer, "w", how) as z:
        for name, array in arrays.items():
            z.writestr(f"{name}.npy", _npy(array))
    return buffer.getvalue()


def lying_member(rnd: random.Random, rows: int, cols: int) -> bytes:
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


def lie_in_directory(rnd: random.Random, data: bytes) -> bytes:
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


# --- h5 ----------------------------------------------------------------------------------


def h5_bytes(rnd: random.Random, rows: int, cols: int) -> tuple[bytes, str]:
    """An HDF5 file made by h5py: valid, or with datasets hostile in one way."""
    import h5py

    frames = rnd.randint(1, 30)
    buffer = io.BytesIO()
    how = "valid"
    with h5py.File(buffer, "w") as f:
        f["time"] = rnd.uniform(-5, 5) + np.arange(frames) / 100.0
        for name in ("left", "right"):
            f[name] = numbers(rnd, (frames, rows, cols))
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
            data = numbers(rnd, (frames,) if victim == "time" else (frames, rows, cols))
            f.create_dataset(
                victim, data=data, chunks=True, shuffle=True, fletcher32=True, compression="gzip"
            )
        elif kind == 10:
            how = "scalar"
            f[victim] = 1.0
        elif kind == 11:
            how = "other shape"
            f[victim] = numbers(rnd, tuple(rnd.randint(0, 4) for _ in range(rnd.randint(0, 4))))
    return buffer.getvalue(), how


# --- vendor ------------------------------------------------------------------------------


def edit_lines(rnd: random.Random, text: bytes) -> bytes:
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
