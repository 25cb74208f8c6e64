"""experiments/set_switches.py: each switch of the labels from a repeated action to
standing, told apart as a pause (the set resumes) or a set's end, with the still frames
the label kept after the last movement and the model's lag. Hand-made frames for the
reading; one real render and replay for the command."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from scotti.models.contract import ACTIONS, NO_ACTION, STANDING
from scotti.sim.corpus import render_scene
from scotti.sim.scene import Scene

from tests.test_experiments_docs import EXPERIMENTS

sys.path.insert(0, str(EXPERIMENTS))

import set_switches
from coverage_grid import Cell, people

SQUAT = ACTIONS.index("squat")
WALKING = ACTIONS.index("walking")


def test_a_pause_and_a_set_end_are_told_apart_with_their_still_frames_and_lags() -> None:
    # squat moving 0-9, still 10-14 (5 frames kept), standing 15-19, squat again 20-24,
    # still 25-26 (2 kept), standing 27-34, then walking 35-39 and standing 40-44.
    truth = np.array(
        [SQUAT] * 15
        + [STANDING] * 5
        + [SQUAT] * 7
        + [STANDING] * 8
        + [WALKING] * 5
        + [STANDING] * 5
    )
    still = np.ones(len(truth), bool)
    still[:10] = still[20:25] = still[35:40] = False
    said = np.full(len(truth), SQUAT)
    said[18] = STANDING  # 3 frames after the pause's switch (15)
    said[27] = STANDING  # at the set end's switch
    switches = set_switches.label_switches(truth, said, still)
    assert [(s.action, s.kind) for s in switches] == [
        ("squat", set_switches.PAUSE),
        ("squat", set_switches.END),
        ("walking", set_switches.END),
    ]
    assert [s.kept_still for s in switches] == [5, 2, 0]
    assert [s.lag for s in switches] == [3, 0, None]  # the model never said standing after 40
    # Said only once the standing is over: not a lag of that standing.
    late = said.copy()
    late[18] = SQUAT
    late[21] = STANDING  # the pause's standing ended at 20
    assert set_switches.label_switches(truth, late, still)[0].lag is None


def test_standing_and_transitions_are_no_switch_of_a_set() -> None:
    truth = np.array([NO_ACTION] * 3 + [STANDING] * 3 + [SQUAT] * 3 + [NO_ACTION] * 3)
    said = np.full(len(truth), STANDING)
    assert set_switches.label_switches(truth, said, np.ones(len(truth), bool)) == []


def test_the_command_reads_a_rendered_session(
    standing_model_path: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    raw = Cell("squat").scene(people(1)[0], 6.0)
    raw["script"][0]["stand_s"] = 3.0
    path = tmp_path / "squat.ses"
    render_scene(Scene.model_validate(raw), path, subject_id="p")
    assert set_switches.main([str(path), "--model", str(standing_model_path)]) == 0
    out = capsys.readouterr().out
    row = next(line for line in out.splitlines() if line.startswith("| `squat` | set end"))
    cells = [c.strip() for c in row.split("|")]
    assert cells[3] == "1"  # one set, one end
    assert cells[5].startswith("0 (0-0)")  # a model that always says standing: no lag
    assert cells[7] == "0"  # and said it in every standing
    assert set_switches.main([str(tmp_path / "missing.ses")]) == 1
