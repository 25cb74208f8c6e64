"""Bad input: one line naming the file, the line and the column (or array and index), exit 2."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scotti.cli.main import main

from tests.support.foreign import pressure_frames, write_pressure_csv

ROWS, COLS = 4, 3


def good_csv(folder: Path, frames: int = 20) -> Path:
    t = np.arange(frames) / 20.0
    path = folder / "p.csv"
    write_pressure_csv(path, t * 1000, pressure_frames(t, ROWS, COLS))
    return path


def run_import(folder: Path, *extra: str) -> int:
    args = ["import", "--grid", f"{ROWS}x{COLS}", "--time-unit", "ms", "--gain", "1"]
    return main([*args, *extra, "-o", str(folder / "out.scotti")])


def one_line(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err.strip()
    assert err.startswith("scotti import: ")
    assert "\n" not in err
    assert "Traceback" not in err
    return err


def edit_line(path: Path, number: int, change: str) -> None:
    lines = path.read_text().splitlines()
    lines[number - 1] = change
    path.write_text("\n".join(lines) + "\n")


def test_a_good_file_imports(tmp_path: Path) -> None:
    assert run_import(tmp_path, "--pressure", str(good_csv(tmp_path))) == 0
    assert (tmp_path / "out.scotti").is_file()


def test_wrong_column_count(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = good_csv(tmp_path)
    lines = path.read_text().splitlines()
    edit_line(path, 7, lines[6] + ",12")
    assert run_import(tmp_path, "--pressure", str(path)) == 2
    err = one_line(capsys)
    assert "p.csv line 7" in err
    assert f"{2 * ROWS * COLS + 2} columns, expected {2 * ROWS * COLS + 1}" in err


def test_declared_grid_does_not_match_the_columns(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = good_csv(tmp_path)
    code = main(["import", "--pressure", str(path), "--grid", "4x4", "-o", str(tmp_path / "o")])
    assert code == 2
    err = one_line(capsys)
    assert "p.csv line 1" in err
    assert "2 feet x 4 x 4 taxels" in err


@pytest.mark.parametrize(
    ("value", "problem"),
    [
        ("nan", "NaN"),
        ("-3", "negative value -3"),
        ("x", "'x' is not"),
        ("1e300", "value 1e+300 too large (float32 holds"),
    ],
)
def test_bad_value_names_line_and_column(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], value: str, problem: str
) -> None:
    path = good_csv(tmp_path)
    cells = path.read_text().splitlines()[4].split(",")
    cells[5] = value
    edit_line(path, 5, ",".join(cells))
    assert run_import(tmp_path, "--pressure", str(path)) == 2
    err = one_line(capsys)
    assert "p.csv line 5, column 6 (L1_1)" in err
    assert problem in err


@pytest.mark.parametrize(("stamp", "kind"), [("100", "duplicate"), ("50", "earlier")])
def test_time_stamps_must_increase(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], stamp: str, kind: str
) -> None:
    path = good_csv(tmp_path)
    cells = path.read_text().splitlines()[3].split(",")  # line 4: t = 100 ms
    cells[0] = stamp
    edit_line(path, 5, ",".join(cells))  # line 5 was 150 ms
    assert run_import(tmp_path, "--pressure", str(path)) == 2
    err = one_line(capsys)
    assert "p.csv line 5, column 1 (t_ms)" in err
    assert kind in err


def test_npz_grid_mismatch_names_the_array(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "p.npz"
    t = np.arange(10) / 10
    np.savez(path, time=t, left=np.zeros((10, ROWS, COLS)), right=np.zeros((10, ROWS, COLS + 1)))
    assert run_import(tmp_path, "--pressure", str(path)) == 2
    assert f"p.npz: right has shape (10, {ROWS}, {COLS + 1})" in one_line(capsys)
    left = np.ones((10, ROWS, COLS))
    left[3, 2, 1] = -1.0
    np.savez(path, time=t, left=left, right=np.zeros((10, ROWS, COLS)))
    assert run_import(tmp_path, "--pressure", str(path)) == 2
    assert "p.npz left[3, 2, 1]: negative value -1" in one_line(capsys)
    np.savez(path, time=t[::-1], left=left, right=left)
    assert run_import(tmp_path, "--pressure", str(path)) == 2
    assert "p.npz time[1]: time stamp earlier" in one_line(capsys)


def test_a_time_array_of_text_is_not_numbers(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The fuzzer's HDF5 finding: text time stamps raised numpy's ValueError."""
    import h5py

    path = tmp_path / "p.h5"
    frames = np.zeros((3, ROWS, COLS))
    with h5py.File(path, "w") as f:
        f["time"] = ["a", "b", "c"]
        f["left"], f["right"] = frames, frames
    assert run_import(tmp_path, "--pressure", str(path)) == 2
    assert "p.h5: time holds object, not numbers" in one_line(capsys)
    np.savez(tmp_path / "p.npz", time=np.array(["1", "2", "3"]), left=frames, right=frames)
    assert run_import(tmp_path, "--pressure", str(tmp_path / "p.npz")) == 2
    assert "p.npz: time holds <U1, not numbers" in one_line(capsys)


def test_unknown_keypoint_set_names_the_config_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    good_csv(tmp_path)
    config = tmp_path / "import.toml"
    config.write_text(
        '[pressure]\nfile = "p.csv"\nrows = 4\ncols = 3\n\n'
        '[keypoints]\nfile = "k.csv"\nset = "openpose_135"\n'
    )
    assert main(["import", str(config), "-o", str(tmp_path / "o.scotti")]) == 2
    err = one_line(capsys)
    assert "import.toml line 8: keypoints.set: Input should be" in err


def test_labels_outside_the_recording(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = good_csv(tmp_path)  # 0 .. 0.95 s
    segments = tmp_path / "seg.csv"
    segments.write_text("start,end,action\n0.0,0.5,squat\n0.5,3.0,lunge\n")
    assert run_import(tmp_path, "--pressure", str(path), "--segments", str(segments)) == 2
    err = one_line(capsys)
    assert "seg.csv line 3, column 2: segment 0.5..3 lies outside the recording (0..0.95)" in err
    segments.write_text("0.0,0.5,dancing\n")
    assert run_import(tmp_path, "--pressure", str(path), "--segments", str(segments)) == 2
    assert "seg.csv line 1, column 3: unknown action 'dancing'" in one_line(capsys)


def test_missing_file_and_existing_output(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert run_import(tmp_path, "--pressure", str(tmp_path / "none.npz")) == 2
    assert "none.npz: no such file" in one_line(capsys)
    path = good_csv(tmp_path)
    assert run_import(tmp_path, "--pressure", str(path)) == 0
    capsys.readouterr()
    assert run_import(tmp_path, "--pressure", str(path)) == 2
    assert "exists; --force replaces it" in one_line(capsys)
    assert run_import(tmp_path, "--pressure", str(path), "--force") == 0


def test_a_header_and_an_empty_row_is_one_line_and_no_warning(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Found by the import fuzz: numpy's reader warned "input contained no data" on stderr
    # before the error line (under pytest's warnings-as-errors: an exception).
    path = tmp_path / "e.csv"
    path.write_bytes(b"t,L0,L1,L2,L3\n,")
    assert main(["import", str(path), "-o", str(tmp_path / "e.scotti"), "--grid", "2x2"]) == 2
    assert "e.csv line 2: 1 columns, expected 5" in one_line(capsys)
