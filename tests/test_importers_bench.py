"""The import bench runs on a tiny input and prints a row per format (no timing is asserted)."""

from __future__ import annotations

from pathlib import Path

import pytest
from scotti.importers import bench

REALDATA = Path(__file__).resolve().parents[2] / "shared" / "realdata"


def rows(out: str) -> dict[str, list[str]]:
    """The first table's rows by format: their cells."""
    table = out.split("\n\n")[0].splitlines()[2:]
    split = ([c.strip() for c in line.split("|")[1:-1]] for line in table)
    return {cells[0]: cells[1:] for cells in split}


def test_a_row_per_table_format_with_a_ratio_to_the_baseline(
    capsys: pytest.CaptureFixture[str],
) -> None:
    args = ["--frames", "300", "--grid", "3x2", "--formats", "csv,npz,h5", "--baseline", "csv"]
    assert bench.main(args) == 0
    out = capsys.readouterr().out
    got = rows(out)
    assert list(got) == ["csv", "npz", "h5"]
    for cells in got.values():
        assert cells[0].startswith("synthetic 3 x 2 at 100 Hz")
        assert cells[1:3] == ["300", "48"]  # source frames; 3 s at 16 Hz
        assert all(float(c) >= 0 for c in cells[3:5])  # CPU seconds
        assert all(float(c.replace(",", "")) > 0 for c in cells[5:])  # rates and the ratio
    assert got["csv"][-1] == "1.00"  # the baseline's own ratio
    assert "| format | read_pressure (CPU s) |" in out  # where the time went
    for fmt, cells in got.items():  # the whole import's two rates, in words
        line = f"{fmt}: {cells[6]} source frames and {cells[7]} output (16 Hz) frames per CPU"
        assert line in out


def test_a_vendor_format_without_its_sample_says_so(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    assert bench.main(["--formats", "pedar", "--realdata", str(tmp_path)]) == 0
    cells = rows(capsys.readouterr().out)["pedar"]
    assert cells[1] == f"no {tmp_path / bench.VENDOR_SAMPLES['pedar']} here"


@pytest.mark.skipif(not REALDATA.is_dir(), reason="no ../shared/realdata here")
def test_each_vendor_sample_imports(capsys: pytest.CaptureFixture[str]) -> None:
    formats = ",".join(bench.VENDOR_SAMPLES)
    assert bench.main(["--formats", formats, "--realdata", str(REALDATA)]) == 0
    got = rows(capsys.readouterr().out)
    assert list(got) == list(bench.VENDOR_SAMPLES)
    for fmt, cells in got.items():
        assert cells[0] == bench.VENDOR_SAMPLES[fmt]
        assert int(cells[1].replace(",", "")) > 0, fmt


def test_every_vendor_reader_has_a_sample() -> None:
    from scotti.importers.vendors import VENDOR_FORMATS

    assert set(VENDOR_FORMATS) == set(bench.VENDOR_SAMPLES)
