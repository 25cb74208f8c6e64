"""experiments/real_tempo.py: a real walk written again at another tempo.

The clock of a gaitpdb file is divided by the tempo and nothing else changes;
the committed 5 s cut of GaCo01 (tests/data/vendors) played at half speed
imports as a 10 s walk at half the cadence.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

EXPERIMENTS = Path(__file__).resolve().parent.parent / "experiments"
sys.path.insert(0, str(EXPERIMENTS))

import real_data  # noqa: E402
import real_tempo  # noqa: E402
import real_vs_sim_gait  # noqa: E402

FIXTURE = Path(__file__).resolve().parent / "data" / "vendors"
MODEL = Path(__file__).resolve().parent.parent / "models" / "scotti-default.onnx"


def test_only_the_time_column_is_divided_by_the_tempo() -> None:
    text = "0.0000\t1.5\t2\n0.0100\t3\t4\n1.0000\t5\t6\n"
    out = real_tempo.retimed_text(text, 0.8).splitlines()
    assert [line.split("\t")[1:] for line in out] == [["1.5", "2"], ["3", "4"], ["5", "6"]]
    assert [float(line.split("\t")[0]) for line in out] == pytest.approx([0.0, 0.0125, 1.25])


def test_a_line_that_is_not_gaitpdb_or_a_bad_tempo_is_refused() -> None:
    with pytest.raises(real_tempo.ExperimentError, match="not a gaitpdb line"):
        real_tempo.retimed_text("time\tL1\n0.0\t1\n", 1.0)
    with pytest.raises(real_tempo.ExperimentError, match="above 0"):
        real_tempo.retimed_text("0.0\t1\n", 0.0)
    assert real_tempo.main(["--tempo", "0", "--model", str(MODEL)]) == 2


def test_paces_fall_in_bands() -> None:
    assert real_tempo.band_of(59.0) == "under 60"
    assert real_tempo.band_of(79.0) == "75-90"
    assert real_tempo.band_of(90.0) == "90-105"
    assert real_tempo.band_of(130.0) == "120 and more"
    assert real_tempo.band_of(None) == "-"


@pytest.mark.slow
def test_a_real_cut_at_half_tempo_walks_at_half_the_cadence(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(real_vs_sim_gait, "CACHE", tmp_path / "cache")
    rec = real_data.Recording("GaCo01_01_first5s.txt", "gaitpdb, 8 sensors", "walking")
    sessions = {t: real_tempo.retimed_session(rec, t, FIXTURE, tmp_path) for t in (1.0, 0.5)}
    assert not list(tmp_path.glob("*.txt"))  # the retimed text is not kept
    cadence = {t: real_data.cadence_of(s) for t, s in sessions.items()}
    assert cadence[1.0] is not None
    assert cadence[0.5] is not None
    assert cadence[0.5] / cadence[1.0] == pytest.approx(0.5, rel=0.1)
    rows = {t: real_data.score_file(rec, s, [MODEL])[0] for t, s in sessions.items()}
    # 5 s at 16 Hz: 80 frames, predictions from frame 40 on; 10 s: 160 frames.
    assert 35 <= rows[1.0]["predictions"] <= 41
    assert 115 <= rows[0.5]["predictions"] <= 121
    table = real_tempo.render(
        [rows[t] | {"tempo": t, "cadence": cadence[t]} for t in (1.0, 0.5)], [1.0, 0.5], "cmd"
    )
    row = next(line for line in table.splitlines() if line.startswith("| GaCo01_01_first5s |"))
    walking = {t: real_data._pct(rows[t]["walking"]) for t in (1.0, 0.5)}
    assert f"{cadence[1.0]:.0f}: {walking[1.0]} | {cadence[0.5]:.0f}: {walking[0.5]} |" in row
    assert "| GaCo02_01 |" not in table  # only the walks measured get rows
    assert table.count(" | 1 | ") == 2  # two pace bands, one walk each
