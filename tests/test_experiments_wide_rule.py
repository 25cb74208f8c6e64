"""experiments/wide_rule.py: the rule that decides whether a candidate ships.

The verdict names every failing line; the real files are pooled as
docs/real-data.md pools them; the squat line renders the scene and scores both
models through ``scotti eval`` (the shipped graph against itself: equal, so
"higher" fails, as it must).
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

EXPERIMENTS = Path(__file__).resolve().parent.parent / "experiments"
sys.path.insert(0, str(EXPERIMENTS))

import real_data  # noqa: E402
import wide_rule  # noqa: E402

MODEL = Path(__file__).resolve().parent.parent / "models" / "scotti-default.onnx"


def line(rule: int, passed: bool) -> wide_rule.Line:
    return wide_rule.Line(rule, "x", 0.5, 0.5, "-", passed)


def test_the_verdict_names_each_failing_line_once() -> None:
    assert wide_rule.verdict([line(1, True), line(2, True)]).startswith("SHIPS")
    text = wide_rule.verdict([line(1, False), line(1, False), line(2, True), line(4, False)])
    assert text == "DOES NOT SHIP: line 1, 4 of the rule fails"


def test_real_files_are_pooled_as_the_real_data_table_pools_them() -> None:
    rows = [
        {"walking": 0.9, "walking_windows": 100},
        {"walking": 0.1, "walking_windows": 300},
        {"walking": None, "walking_windows": 0},  # a file without walking spans
    ]
    share = wide_rule.pooled_share(rows, "walking", "walking_windows")
    assert share == pytest.approx((90 + 30) / 400)
    assert real_data._pct(share) == real_data._pooled(rows, "walking", "walking_windows")


def test_the_held_out_people_are_partition_p1s_test_people() -> None:
    import json

    parts = json.loads((EXPERIMENTS / "partitions.json").read_text())["partitions"]
    p1 = next(p for p in parts if p["name"] == "p1")
    expected = [wide_rule.HELD_OUT_DIR / f"{s}.ses" for s in p1["test"]]
    if not all(f.is_file() for f in expected):  # a checkout without the corpus says so
        with pytest.raises(wide_rule.ExperimentError, match="missing held-out sessions"):
            wide_rule.held_out_sessions()
        return
    assert wide_rule.held_out_sessions() == expected


def test_held_out_people_come_from_the_folder_given(tmp_path: Path) -> None:
    import json

    parts = json.loads((EXPERIMENTS / "partitions.json").read_text())["partitions"]
    p1 = next(p for p in parts if p["name"] == "p1")
    with pytest.raises(wide_rule.ExperimentError, match=str(tmp_path)):
        wide_rule.held_out_sessions(tmp_path)
    for subject in p1["test"]:
        (tmp_path / f"{subject}.ses").write_bytes(b"")
    assert wide_rule.held_out_sessions(tmp_path) == [tmp_path / f"{s}.ses" for s in p1["test"]]


@pytest.mark.slow
def test_the_squat_line_renders_the_scene_and_needs_a_higher_accuracy(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(wide_rule, "WORK", tmp_path)
    (squat,) = wide_rule.squat_lines(MODEL, MODEL)
    assert (tmp_path / "squat.scotti").is_file()
    assert 0.0 < squat.candidate <= 1.0
    assert squat.candidate == squat.shipped  # the same graph on the same replay
    assert not squat.passed  # "higher" is not met by an equal model
