"""The import readers under the fuzzer: a short seeded run of each target, and its machinery."""

from __future__ import annotations

import random
from pathlib import Path

import pytest
from scotti.daemon.tools import fuzz, fuzz_imports
from scotti.daemon.tools.fuzz_imports import ImportCase, IsolatedCheck, Seeds, check_import

INPUTS = 120  # per target: a few hundred in all, seeded; the long run is the command
HAS_REALDATA = fuzz_imports.REALDATA.is_dir()


def findings(name: str, tmp_path: Path) -> list[str]:
    outcome = fuzz.fuzz(name, INPUTS, 0, tmp_path, 0, float("inf"))
    assert outcome.inputs == INPUTS
    return list(outcome.findings)


@pytest.mark.parametrize("name", ["csv", "npz", "h5"])
def test_a_short_seeded_run_of_a_table_format_finds_nothing(name: str, tmp_path: Path) -> None:
    assert findings(name, tmp_path) == []


@pytest.mark.skipif(not HAS_REALDATA, reason="no ../shared/realdata here")
def test_a_short_seeded_run_of_the_vendor_readers_finds_nothing(tmp_path: Path) -> None:
    assert findings("vendor", tmp_path) == []


def test_every_kind_of_input_is_drawn(tmp_path: Path) -> None:
    """The makers reach their hostile kinds, not only valid files."""
    seeds = Seeds(tmp_path)
    rnd = random.Random(0)
    for name, maker in fuzz_imports.MAKERS.items():
        if name == "vendor" and not HAS_REALDATA:
            continue  # the vendor maker mutates the heads of ../shared/realdata's samples
        kinds = {maker(rnd, seeds).how.split(",")[0] for _ in range(200)}
        assert "valid" in kinds or name == "vendor"
        assert len(kinds) >= 4, (name, kinds)


def test_the_bombs_are_refused_by_the_budget_not_the_allocator(tmp_path: Path) -> None:
    seeds = Seeds(tmp_path)
    assert len(seeds.npz_bomb()) < 1_000_000
    check_import(ImportCase("npz", ".npz", seeds.npz_bomb(), 2, 2, "a bomb"), tmp_path)
    check_import(ImportCase("vendor", ".txt.gz", seeds.gzip_bomb(), how="a bomb"), tmp_path)


def test_what_the_worker_cannot_do_is_a_finding(tmp_path: Path) -> None:
    """With no address space left the import cannot even load: a finding, not a stop."""
    check = IsolatedCheck(tmp_path / "w", memory=1)
    case = ImportCase("csv", ".csv", b"0,1,2\n0.1,1,2\n", 1, 1, "valid")
    try:
        with pytest.raises(fuzz_imports.FindingError, match=r"MemoryError|died"):
            check(case)
        with pytest.raises(fuzz_imports.FindingError, match=r"MemoryError|died"):
            check(case)  # the worker goes on, or a new one starts
    finally:
        check.close()
    roomy = IsolatedCheck(tmp_path / "w2")
    try:
        roomy(case)  # passes: a clean import
    finally:
        roomy.close()


def test_a_finding_s_file_is_kept(tmp_path: Path) -> None:
    case = ImportCase("csv", ".csv", b"t,a\n1,x\n", 1, 1, "made here")
    fuzz._keep(tmp_path, "csv", 0, case)
    assert (tmp_path / "csv-0.csv").read_bytes() == case.data
    assert "made here" in (tmp_path / "csv-0.input.txt").read_text()


def test_the_command_runs_the_import_targets(capsys: pytest.CaptureFixture[str]) -> None:
    args = ["--targets", "csv,npz", "--inputs", "40", "--progress", "0", "--seed", "5"]
    assert fuzz.main(args) == 0
    out = capsys.readouterr().out
    assert "| csv | 20 | 0 |" in out
    assert "| npz | 20 | 0 |" in out
