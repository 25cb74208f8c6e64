"""``scotti import`` under a 1 GiB address-space limit: hostile sizes are one line and exit 2.

Each import runs in a child process with ``RLIMIT_AS`` set (as ``ulimit -v``
would), behind a small wrapper that reports the child's peak resident
memory. The files are the issue's: an HDF5 file of a few kB declaring 10^9
samples, a 1 MB ``.npz`` that inflates to 1 GiB, a 10 MB CSV.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import zipfile
from pathlib import Path

import h5py
import numpy as np
import pytest

LIMIT = 1 << 30
ROWS, COLS = 4, 3
WRAPPER = (
    "import resource, subprocess, sys\n"
    "def limit():\n"
    f"    resource.setrlimit(resource.RLIMIT_AS, ({LIMIT}, {LIMIT}))\n"
    "code = subprocess.run(sys.argv[1:], preexec_fn=limit).returncode\n"
    "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)\n"
    "sys.exit(code)\n"
)

pytestmark = pytest.mark.skipif(not hasattr(resource, "RLIMIT_AS"), reason="no RLIMIT_AS")


def scotti_import(
    folder: Path, pressure: Path, **env: str
) -> tuple[int, list[str], list[str], int]:
    """(exit status, stdout lines, stderr lines, peak RSS in MiB) of a limited import."""
    command = [sys.executable, "-c", WRAPPER, sys.executable, "-m", "scotti.cli.main", "import"]
    command += ["--pressure", str(pressure), "--grid", f"{ROWS}x{COLS}", "--gain", "1"]
    command += ["--time-unit", "ms", "-o", str(folder / "out.scotti"), "--force"]
    environment = {k: v for k, v in os.environ.items() if not k.startswith("SCOTTI_")}
    environment |= {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", **env}
    done = subprocess.run(command, capture_output=True, text=True, env=environment, timeout=240)
    out = done.stdout.strip().splitlines()
    return done.returncode, out[:-1], done.stderr.strip().splitlines(), int(out[-1]) // 1024


def one_line(code: int, err: list[str]) -> str:
    assert code == 2, err
    assert len(err) == 1, err
    assert err[0].startswith("scotti import: ")
    return err[0]


def test_an_hdf5_file_of_a_few_kb_declaring_a_billion_samples(tmp_path: Path) -> None:
    path = tmp_path / "p.h5"
    with h5py.File(path, "w") as f:
        f.create_dataset("time", shape=(10**9,), dtype="f8")  # contiguous, never written
        f["left"] = f["right"] = np.zeros((10, ROWS, COLS))
    assert path.stat().st_size < 4_000
    code, _, err, peak = scotti_import(tmp_path, path)
    assert "p.h5 time: declares (1000000000) float64 (8 GB) but the file stores 0" in one_line(
        code, err
    )
    assert peak < 300


def write_npz_bomb(path: Path, nbytes: int) -> None:
    """``left`` of ``nbytes`` zeros, deflated; ``time`` and ``right`` of 10 frames."""
    frames = nbytes // (ROWS * COLS * 8)
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        for name, array in (("time", np.arange(10) * 10.0), ("right", np.zeros((10, ROWS, COLS)))):
            with z.open(f"{name}.npy", "w") as f:
                np.lib.format.write_array(f, array)
        with z.open("left.npy", "w", force_zip64=True) as f:
            header = {"descr": "<f8", "fortran_order": False, "shape": (frames, ROWS, COLS)}
            np.lib.format.write_array_header_1_0(f, header)
            left = frames * ROWS * COLS * 8
            block = bytes(1 << 22)
            while left:
                f.write(block[: min(left, len(block))])
                left -= min(left, len(block))


def test_a_1_mb_npz_that_inflates_to_a_gigabyte(tmp_path: Path) -> None:
    path = tmp_path / "p.npz"
    write_npz_bomb(path, 1 << 30)
    assert path.stat().st_size < 1_200_000
    code, _, err, peak = scotti_import(tmp_path, path)
    message = one_line(code, err)
    frames = (1 << 30) // (ROWS * COLS * 8)
    assert f"p.npz left: ({frames}, {ROWS}, {COLS}) float64 needs 1.07 GB, more than" in message
    assert peak < 300


def test_a_memory_error_is_one_line_too(tmp_path: Path) -> None:
    """With the budget raised past the limit, the allocation itself fails: still one line."""
    path = tmp_path / "p.h5"
    with h5py.File(path, "w") as f:  # compressed, so its size is not checked against the file
        f.create_dataset("time", shape=(10**9,), dtype="f8", chunks=(10**6,), compression="gzip")
        f["left"] = f["right"] = np.zeros((10, ROWS, COLS))
    code, _, err, _ = scotti_import(tmp_path, path, SCOTTI_IMPORT_MAX_BYTES="100G")
    assert "out of memory" in one_line(code, err)


def write_csv(path: Path, frames: int, last: str | None = None) -> None:
    t = np.arange(frames) * 10.0
    body = np.column_stack([t, np.full((frames, 2 * ROWS * COLS), 12.5)])
    np.savetxt(path, body, delimiter=",", fmt="%.1f")
    if last is not None:
        with path.open("a") as f:
            f.write(last + "\n")


def test_a_10_mb_csv_imports_in_a_bounded_memory(tmp_path: Path) -> None:
    path = tmp_path / "p.csv"
    write_csv(path, 80_000)
    assert 9e6 < path.stat().st_size < 12e6
    code, out, err, peak = scotti_import(tmp_path, path)
    assert code == 0, err
    assert "from 80000 source frames" in out[0]
    assert peak < 400


def test_a_10_mb_csv_with_a_mistake_on_its_last_line(tmp_path: Path) -> None:
    path = tmp_path / "p.csv"
    write_csv(path, 80_000, last="1000000.0," + ",".join(["1"] * 23) + ",x")
    code, _, err, peak = scotti_import(tmp_path, path)
    assert "p.csv line 80001, column 25: 'x' is not a number" in one_line(code, err)
    assert peak < 400


def test_the_budget_is_the_least_of_its_bounds(monkeypatch: pytest.MonkeyPatch) -> None:
    from scotti.importers import limits
    from scotti.importers.errors import ImporterError

    monkeypatch.delenv(limits.ENV_VAR, raising=False)
    half = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE") // 2
    assert limits.budget(1_000)[0] == min(limits.FLOOR_BYTES, half)
    assert limits.budget(10_000_000)[0] == min(100 * 10_000_000, half)
    monkeypatch.setenv(limits.ENV_VAR, "2G")
    assert limits.budget(1_000) == (2 << 30, f"{limits.ENV_VAR} allows")
    monkeypatch.setenv(limits.ENV_VAR, "lots")
    with pytest.raises(ImporterError, match="SCOTTI_IMPORT_MAX_BYTES='lots': want a size"):
        limits.budget(1_000)


def test_a_budget_says_what_is_left_when_it_refuses() -> None:
    from scotti.importers.errors import InputError
    from scotti.importers.limits import Budget

    budget = Budget("f.npz", total=3_000_000)
    budget.take(2_000_000, "time")
    with pytest.raises(InputError) as caught:
        budget.take(2_000_000, "left", column="left")
    assert str(caught.value) == (
        "f.npz left: left needs 2 MB, more than this read may take (1 MB left of 3 MB); "
        "SCOTTI_IMPORT_MAX_BYTES raises it"
    )
