"""Named arrays from ``.npz`` and HDF5 files, every size checked before it is allocated.

An array's declared shape and type are a promise; these readers hold it to
the file: an ``.npz`` member's header must describe exactly the bytes the
zip directory says the member unpacks to, an uncompressed HDF5 dataset
must have its bytes stored in the file, and whatever passes must fit the
read's memory budget (``limits``: this is what stops a compressed member
of zeros that inflates to gigabytes). Only then is the array allocated,
once, and filled in place. Arrays hold numbers (bool, int, float) or text;
anything else (pickled objects, records, complex numbers, references) is
refused by name.

HDF5 needs h5py (the ``[import]`` extra), imported only when an HDF5 file
is read.
"""

from __future__ import annotations

import math
import struct
import tokenize
import warnings
import zipfile
import zlib
from pathlib import Path
from typing import IO, Any, Final

import numpy as np
from scotti.importers.errors import InputError, clip
from scotti.importers.limits import Budget, size_text

HDF5_SUFFIXES: Final = (".h5", ".hdf5", ".hdf")
_KINDS: Final = "biufSU"  # numbers and text; h5py's variable-length strings besides
_MAX_TEXT_ITEMS: Final = 100_000  # strings in one array: names, not data
_LISTED: Final = 12  # array names an error lists
_READ_BYTES: Final = 1 << 20  # what a member is read in
# What zipfile and zlib raise on a damaged archive (zipfile's own checks are not all
# BadZipFile: a cut directory entry is an IndexError, a bad extra field a struct.error).
_ZIP_ERRORS: Final = (
    zipfile.BadZipFile,
    zipfile.LargeZipFile,
    zlib.error,
    struct.error,
    OSError,
    EOFError,
    ValueError,
    IndexError,
    KeyError,
    OverflowError,
    NotImplementedError,  # a zip version, a compression or an encryption it does not know
)


def load_arrays(path: Path, keys: list[str]) -> dict[str, np.ndarray]:
    """Named arrays from an ``.npz`` (names) or an HDF5 file (dataset paths).

    A key ending in ``?`` is optional (left out of the result when absent).
    """
    suffix = path.suffix.lower()
    if not path.is_file():
        raise InputError(path, "no such file")
    names = [k.rstrip("?") for k in keys]
    budget = Budget(path)
    try:
        if suffix == ".npz":
            found, available = _read_npz(path, names, budget)
        elif suffix in HDF5_SUFFIXES:
            found, available = _read_hdf5(path, names, budget)
        else:
            raise InputError(path, f"unknown file type {suffix!r} (.csv, .npz, .h5, .hdf5)")
    except MemoryError:  # the budget is a share of memory; the rest of the machine may be busy
        raise InputError(path, "out of memory while reading it") from None
    for key in keys:
        if not key.endswith("?") and key not in found:
            shown = ", ".join(clip(a, 40) for a in available[:_LISTED])
            shown += " ..." if len(available) > _LISTED else ""
            raise InputError(path, f"no array {clip(key, 40)!r} (it has: {shown or 'nothing'})")
    return found


def _shape_text(shape: tuple[int, ...], dtype: np.dtype[Any]) -> str:
    return f"({', '.join(map(str, shape))}) {dtype}"


def _check_dtype(path: Path, name: str, dtype: np.dtype[Any]) -> None:
    if dtype.kind not in _KINDS or dtype.fields is not None or dtype.subdtype is not None:
        problem = f"holds {clip(str(dtype), 60)} values, not numbers or text"
        raise InputError(path, problem, column=name)
    if dtype.itemsize == 0:  # numpy would make them one byte each: sizes would not add up
        raise InputError(path, f"holds values of no size ({dtype})", column=name)


# --- .npz ---------------------------------------------------------------------------------


def _read_npz(
    path: Path, names: list[str], budget: Budget
) -> tuple[dict[str, np.ndarray], list[str]]:
    found: dict[str, np.ndarray] = {}
    try:
        with zipfile.ZipFile(path) as z:
            members = {
                i.filename.removesuffix(".npy"): i
                for i in z.infolist()
                if i.filename and not i.filename.endswith("/")
            }
            for name in names:
                if name in members and name not in found:
                    found[name] = _read_member(path, z, members[name], name, budget)
    except _ZIP_ERRORS as exc:
        raise InputError(path, f"not a readable .npz ({exc.__class__.__name__})") from None
    return found, list(members)


def _read_member(
    path: Path, z: zipfile.ZipFile, info: zipfile.ZipInfo, name: str, budget: Budget
) -> np.ndarray:
    """One member: its header checked against the zip directory, then read in place."""
    try:
        with z.open(info) as f:
            shape, fortran, dtype, header_bytes = _npy_header(f)
            _check_dtype(path, name, dtype)
            count = math.prod(shape)
            nbytes = count * dtype.itemsize
            stored = info.file_size - header_bytes
            if nbytes != stored:
                problem = f"declares {_shape_text(shape, dtype)} ({size_text(nbytes)}) but "
                problem += f"the zip holds {size_text(max(stored, 0))} for it"
                raise InputError(path, problem, column=name)
            budget.take(nbytes, f"{_shape_text(shape, dtype)}", column=name)
            flat = np.empty(count, dtype=dtype)
            _fill(path, name, f, flat)
    except InputError:
        raise
    except (*_ZIP_ERRORS, tokenize.TokenError, RecursionError, RuntimeError) as exc:
        problem = f"not a readable array ({exc.__class__.__name__}: {clip(str(exc), 60)})"
        raise InputError(path, problem, column=name) from None
    if fortran:
        return flat.reshape(shape[::-1]).transpose()
    return flat.reshape(shape)


def _npy_header(f: IO[bytes]) -> tuple[tuple[int, ...], bool, np.dtype[Any], int]:
    """(shape, Fortran order, dtype, bytes before the data) of an .npy stream."""
    fmt = np.lib.format
    version = fmt.read_magic(f)
    with warnings.catch_warnings():  # a header written by Python 2 is read all the same
        warnings.simplefilter("ignore", UserWarning)
        if version == (1, 0):
            shape, fortran, dtype = fmt.read_array_header_1_0(f)
        elif version == (2, 0):
            shape, fortran, dtype = fmt.read_array_header_2_0(f)
        else:
            raise ValueError(f"npy format {version[0]}.{version[1]}")
    return tuple(int(n) for n in shape), bool(fortran), np.dtype(dtype), f.tell()


def _fill(path: Path, name: str, f: IO[bytes], flat: np.ndarray) -> None:
    """Read exactly ``flat``'s bytes from ``f`` into it, a block at a time."""
    if flat.nbytes == 0:
        return
    view = flat.view(np.uint8)
    done = 0
    while done < view.size:
        data = f.read(min(view.size - done, _READ_BYTES))
        if not data:
            problem = f"cut short: {size_text(done)} of {size_text(view.size)}"
            raise InputError(path, problem, column=name)
        view[done : done + len(data)] = np.frombuffer(data, dtype=np.uint8)
        done += len(data)


# --- HDF5 ---------------------------------------------------------------------------------


def _read_hdf5(
    path: Path, names: list[str], budget: Budget
) -> tuple[dict[str, np.ndarray], list[str]]:
    try:
        import h5py  # the [import] extra; only HDF5 files need it
    except ModuleNotFoundError:
        raise InputError(path, "reading HDF5 needs h5py: pip install 'scotti[import]'") from None
    found: dict[str, np.ndarray] = {}
    available: list[str] = []
    try:
        with h5py.File(path, "r") as f:

            def listed(name: str | bytes, obj: Any) -> bool | None:
                if isinstance(obj, h5py.Dataset):  # a name that is not UTF-8 comes as bytes
                    available.append(name if isinstance(name, str) else name.decode("latin-1"))
                return len(available) > _LISTED or None  # enough for a message: stop

            f.visititems(listed)
            for name in names:
                obj = f.get(name) if name and name not in found else None
                if isinstance(obj, h5py.Dataset):
                    found[name] = _read_dataset(path, h5py, obj, name, budget)
    except InputError:
        raise
    except (OSError, KeyError, ValueError, RuntimeError, TypeError) as exc:
        problem = f"not a readable HDF5 file ({clip(str(exc) or exc.__class__.__name__, 80)})"
        raise InputError(path, problem) from None
    return found, available


def _read_dataset(path: Path, h5py: Any, dset: Any, name: str, budget: Budget) -> np.ndarray:
    """One dataset: its declared size against what the file stores, then read in place."""
    if dset.shape is None:
        raise InputError(path, "holds no data (an empty dataspace)", column=name)
    shape = tuple(int(n) for n in dset.shape)
    dtype = np.dtype(dset.dtype)
    count = math.prod(shape)
    if h5py.check_string_dtype(dtype) is not None and dtype.kind == "O":
        return _read_strings(path, dset, name, count, budget)
    _check_dtype(path, name, dtype)
    nbytes = count * dtype.itemsize
    plist = dset.id.get_create_plist()
    if dset.is_virtual or plist.get_external_count() > 0:
        raise InputError(path, "its data lie in other files (not read)", column=name)
    stored = int(dset.id.get_storage_size())
    if plist.get_nfilters() == 0 and nbytes > stored:
        problem = f"declares {_shape_text(shape, dtype)} ({size_text(nbytes)}) but the file "
        problem += f"stores {size_text(stored)} of it"
        raise InputError(path, problem, column=name)
    if dset.chunks is not None:  # the library unpacks a whole chunk at a time
        chunk = math.prod(dset.chunks) * dtype.itemsize
        budget.take(chunk, "one chunk", column=name)
        budget.give_back(chunk)
    budget.take(nbytes, _shape_text(shape, dtype), column=name)
    out = np.empty(shape, dtype=dtype)
    if count:
        try:
            dset.read_direct(out)
        except (OSError, ValueError, RuntimeError, TypeError) as exc:
            problem = f"cannot be read ({clip(str(exc) or exc.__class__.__name__, 80)})"
            raise InputError(path, problem, column=name) from None
    return out


def _read_strings(path: Path, dset: Any, name: str, count: int, budget: Budget) -> np.ndarray:
    """Variable-length strings (names): a few, each kept in the file's own heap."""
    if count > _MAX_TEXT_ITEMS:
        raise InputError(path, f"{count} strings, more than names would need", column=name)
    budget.take(count * 64 + path.stat().st_size, f"{count} strings", column=name)
    return np.asarray(dset.asstr()[()], dtype=object)
