"""experiments/real_data.py: a real recording imported, replayed and scored per file.

The committed 5 s cut of gaitpdb GaCo01 (tests/data/vendors, source in its
README) goes through ``scotti import`` and the daemon's path with the shipped
model, as the command does with every file of ../shared/realdata.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

EXPERIMENTS = Path(__file__).resolve().parent.parent / "experiments"
sys.path.insert(0, str(EXPERIMENTS))

import real_data  # noqa: E402
import real_vs_sim_gait  # noqa: E402

FIXTURE = Path(__file__).resolve().parent / "data" / "vendors"
MODEL = Path(__file__).resolve().parent.parent / "models" / "scotti-default.onnx"


def test_the_truth_follows_the_spans_of_quiet_standing() -> None:
    rec = real_data.Recording("x/a.txt", "s", "walking", standing=((0.0, 2.0),))
    truth = real_data.truth_at(rec, np.array([0.5, 2.0, 2.1, 9.0]))
    from scotti.models.contract import ACTIONS

    assert [ACTIONS[a] for a in truth] == ["standing", "standing", "walking", "walking"]


@pytest.mark.slow
def test_a_real_cut_is_imported_scored_and_tabled(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    rec = real_data.Recording("GaCo01_01_first5s.txt", "gaitpdb, 8 sensors", "walking")
    session = real_data.import_file(rec, FIXTURE, tmp_path)
    assert session.is_file()
    again = real_data.import_file(rec, FIXTURE, tmp_path)  # kept, not imported twice
    assert again.stat().st_mtime == session.stat().st_mtime
    (row,) = real_data.score_file(rec, session, [MODEL])
    # 5 s at 16 Hz is 80 frames; the first prediction is for frame T = 40.
    assert 35 <= row["predictions"] <= 41
    assert row["walking_windows"] == row["predictions"]
    for key in ("walking", "unfamiliar", "out_of_range", "confident_wrong"):
        assert 0.0 <= row[key] <= 1.0
    assert sum(row["actions"].values()) == row["predictions"]
    assert row["confident_wrong_unflagged"] <= row["confident_wrong"]
    # Published walking: read as walking and not withheld, so never above walking, and
    # below it by at most the flagged share.
    assert row["walking"] - row["unfamiliar"] - 1e-9 <= row["walking_published"] <= row["walking"]
    monkeypatch.setattr(real_vs_sim_gait, "CACHE", tmp_path / "cache")
    cadence = real_data.cadence_of(session)
    assert cadence is not None
    assert 80.0 < cadence < 120.0  # GaCo01 walks at about 98 steps a minute
    text = real_data.table([rec], [row | {"cadence": cadence}], "python experiments/real_data.py")
    assert f"| GaCo01_01_first5s | gaitpdb, 8 sensors | walking | {cadence:.0f} |" in text
    assert "Pooled over the files" in text
    assert "| model | walking | walking, published | standing |" in text


def test_where_the_person_stands_still_a_walking_file_is_not_scored() -> None:
    rec = real_data.Recording("x/a.txt", "s", "walking", standing=((0.0, 1.0),))
    still = np.array([True, False, True, True])
    truth = real_data.truth_at(rec, np.array([0.5, 2.0, 3.0, 9.0]), still)
    from scotti.models.contract import ACTIONS

    # A declared span of quiet standing stays standing; other still times are unscored.
    assert truth[0] == ACTIONS.index("standing")
    assert truth[1] == ACTIONS.index("walking")
    assert truth[2:].tolist() == [real_data.UNSCORED] * 2


@pytest.mark.slow
def test_a_walk_that_ends_standing_has_its_end_found_and_left_unscored(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The committed 5 s of GaCo01 walking, then 3 s of its first row (both feet loaded).
    lines = (FIXTURE / "GaCo01_01_first5s.txt").read_text().splitlines()
    rest = lines[0].split("\t")[1:]
    lines += ["\t".join([f"{5.0 + k / 100:.4f}", *rest]) for k in range(300)]
    (tmp_path / "walk_then_stand.txt").write_text("\n".join(lines) + "\n")
    monkeypatch.setattr(real_vs_sim_gait, "CACHE", tmp_path / "cache")
    rec = real_data.Recording("walk_then_stand.txt", "gaitpdb, 8 sensors", "walking")
    session = real_data.import_file(rec, tmp_path, tmp_path / "work")
    still = real_data.still_slots(session)
    assert still[-40:].all()  # the last 2.5 s: both feet down
    assert not still[16:64].any()  # 1-4 s: walking
    (row,) = real_data.score_file(rec, session, [MODEL])
    # The last 3 s are 48 predictions; the step into the stand may add a few frames.
    assert 48 <= round(row["still"] * row["predictions"]) <= 60
    assert row["walking_windows"] == round(row["predictions"] * (1 - row["still"]))


def test_the_card_quotes_the_table_only_of_the_shipped_model_on_every_file(tmp_path: Path) -> None:
    every = list(real_data.RECORDINGS)
    shipped = [real_data.DEFAULT_MODEL]
    assert real_data.quotes_in_card(real_data.DOC, shipped, every)
    assert not real_data.quotes_in_card(None, shipped, every)  # printed, not written
    assert not real_data.quotes_in_card(tmp_path / "x.md", shipped, every)
    assert not real_data.quotes_in_card(real_data.DOC, [tmp_path / "cand.onnx"], every)
    assert not real_data.quotes_in_card(real_data.DOC, [*shipped, tmp_path / "c.onnx"], every)
    assert not real_data.quotes_in_card(real_data.DOC, shipped, every[:2])  # --only
