"""experiments/set_end_latency.py reads, frame by frame, how long a model goes on
naming a set after its label has turned to standing. Real renders, real onnxruntime:
a graph that always says standing switches at the first standing frame, one that
never does is counted as never."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pytest
from scotti.models.contract import SET_EDGE_REST_S
from scotti.models.kv_streaming import open_step_model
from scotti.sim.scene import Scene

from tests.support.fixtures_models import TINY_STEP, always_standing
from tests.test_experiments_docs import EXPERIMENTS

sys.path.insert(0, str(EXPERIMENTS))

import set_end_latency
from coverage_grid import Cell, people


def _squat_then_still(seconds: float = 6.0, stand_s: float = 4.0) -> Scene:
    raw = Cell("squat").scene(people(1)[0], seconds)
    raw["script"][0]["stand_s"] = stand_s
    return Scene.model_validate(raw)


def test_longest_run_counts_the_longest_stretch_of_true() -> None:
    runs = set_end_latency._longest_run
    assert runs(np.array([True, True, False, True, True, True, False])) == 3
    assert runs(np.array([False, False])) == 0
    assert runs(np.zeros(0, bool)) == 0


def test_a_model_that_says_standing_switches_at_the_label(
    standing_model_path: Path, tmp_path: Path
) -> None:
    model = open_step_model(standing_model_path)
    end = set_end_latency.set_end("squat", _squat_then_still(), model, tmp_path)
    assert end.lag_frames == 0
    assert end.wrong_after == 0  # it said standing on every standing frame after the set
    assert end.wrong > 0  # and standing on the squats too
    assert end.lag_from_still is not None
    assert end.lag_from_still >= 0
    # The labels keep some still standing in the set after its last movement, at most the
    # convention's bound; the lag from that movement is the lag from the label plus it.
    assert end.kept_still is not None
    assert 0 <= end.kept_still <= round(SET_EDGE_REST_S * 16)
    assert end.lag_from_still == end.lag_frames + end.kept_still + 1
    # 4 s still after the set, less at most SET_EDGE_REST_S kept in it: 3-4 s of standing.
    assert 3 * 16 <= end.standing_frames <= 4 * 16 + 1
    assert end.longest_pause >= 0
    assert not list(tmp_path.iterdir())  # the render is not left behind


def test_a_model_that_never_says_standing_is_counted_as_never(tmp_path: Path) -> None:
    never = always_standing(TINY_STEP, tmp_path / "never-standing.onnx", margin=-50.0)
    model = open_step_model(never)
    ends = [set_end_latency.set_end("squat", _squat_then_still(), model, tmp_path)]
    assert ends[0].lag_frames is None
    assert ends[0].wrong_after == ends[0].standing_frames  # every standing frame after it wrong
    assert ends[0].lag_from_still is None
    assert ends[0].kept_still is not None  # the labels' edge does not depend on the model
    args = argparse.Namespace(people=1, seconds=6.0, stand_s=4.0)
    text = set_end_latency.markdown(ends, args, never)
    row = next(line for line in text.splitlines() if line.startswith("| `squat`"))
    assert row.split("|")[3].strip() == "-"  # no lag to show
    assert row.split("|")[-2].strip() == "1"  # never said standing: one person
    assert row.split("|")[-3].strip() == f"{ends[0].wrong_after} of {ends[0].wrong}"
    assert "--people 1 --seconds 6 --stand-s 4" in text


def test_a_session_without_a_set_followed_by_standing_is_refused(
    standing_model_path: Path, tmp_path: Path
) -> None:
    model = open_step_model(standing_model_path)
    with pytest.raises(set_end_latency.ModelError, match="no set followed by standing"):
        set_end_latency.set_end("lunge", _squat_then_still(), model, tmp_path)
