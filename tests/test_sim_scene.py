"""Scene files: validation with field and line, shipped scenes, subjects."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scotti.models.contract import ACTIONS, NO_ACTION, STANDING, has_progress
from scotti.sim import SimError
from scotti.sim.scene import Scene, SceneError, build_motion, load_scene
from scotti.sim.subjects import BMI_RANGE, HEIGHT_RANGE_M, draw_subjects
from scotti.sim.traits import TYPICAL_CADENCE_SPM

SCENES = Path(__file__).resolve().parents[1] / "sim" / "scenes"

GOOD = """\
seed = 7
rate = 16.0

[subject]
height_m = 1.75
mass_kg = 70.0
style_seed = 3

[[script]]
action = "squat"
reps = 2

[[script]]
action = "walking"
duration_s = 4.0
tempo = 1.1

[[script]]
action = "step_up"
reps = 1
step_height_m = 0.25
"""


def _error(text: str) -> str:
    with pytest.raises(SceneError) as caught:
        Scene.from_toml_text(text, "scene.toml")
    message = str(caught.value)
    assert "\n" not in message
    return message


def test_a_good_scene_loads_and_builds() -> None:
    scene = Scene.from_toml_text(GOOD, "good.toml")
    assert scene.name == "good"
    assert [s.action for s in scene.script] == ["squat", "walking", "step_up"]
    motion = build_motion(scene)
    assert motion.rate_hz == 16.0
    assert set(np.unique(motion.action)) == {STANDING, 0, 2, 7}  # the stands are standing
    assert motion.subject.height_m == 1.75


@pytest.mark.parametrize(
    ("old", "new", "expected"),
    [
        (
            "reps = 2\n",
            "reps = 0\n",
            "scene.toml line 11: script[0].reps: Input should be greater than 0",
        ),
        (
            "tempo = 1.1",
            "tempo = 'fast'",
            "scene.toml line 16: script[1].tempo: Input should be a valid number",
        ),
        (
            'action = "step_up"',
            'action = "hop"',
            "scene.toml line 19: script[2].action: Input should be",
        ),
        (
            "height_m = 1.75",
            "height_m = 3.0",
            "scene.toml line 5: subject.height_m: Input should be less",
        ),
        (
            "step_height_m = 0.25",
            "step_hieght_m = 0.25",
            "scene.toml line 21: script[2].step_hieght_m: Extra inputs",
        ),
        (
            "reps = 1\n",
            "reps = 1\nduration_s = 3\n",
            "scene.toml line 18: script[2]: Value error, give exactly one",
        ),
        ("mass_kg = 70.0\n", "", "scene.toml line 4: subject.mass_kg: Field required"),
        ("seed = 7", "seed = 1.5", "scene.toml line 1: seed: Input should be a valid integer"),
    ],
)
def test_a_bad_field_is_named_with_its_line(old: str, new: str, expected: str) -> None:
    assert old in GOOD
    assert _error(GOOD.replace(old, new, 1)).startswith(expected)


def test_toml_syntax_errors_name_the_line() -> None:
    message = _error(GOOD.replace("rate = 16.0", "rate = = 16.0"))
    assert message.startswith("scene.toml line 2: ")


def test_an_unknown_effect_is_named_with_its_line() -> None:
    message = _error(GOOD + '\n[[effects]]\nname = "noise"\n\n[[effects]]\nname = "gremlins"\n')
    assert message.startswith("scene.toml line 26: effects[1]: ")
    assert "gremlins" in message


def test_load_scene_reports_a_missing_file_in_one_line(tmp_path: Path) -> None:
    with pytest.raises(SimError, match="cannot read scene"):
        load_scene(tmp_path / "nope.toml")
    path = tmp_path / "mine.toml"
    path.write_text(GOOD.replace("reps = 2\n", "reps = -1\n"), encoding="utf-8")
    with pytest.raises(SceneError, match=r"^mine\.toml line 11: script\[0\]\.reps"):
        load_scene(path)


@pytest.mark.parametrize("path", sorted(SCENES.glob("*.toml")), ids=lambda p: p.stem)
def test_shipped_scenes_validate(path: Path) -> None:
    scene = load_scene(path)
    assert scene.script or scene.session is not None
    assert scene.description


def test_one_scene_per_action_and_an_all_actions_scene() -> None:
    # Standing needs no scene of its own: every scene's stands are labelled standing.
    exercises = [a for i, a in enumerate(ACTIONS) if has_progress(i)]
    for action in exercises:
        scene = load_scene(SCENES / f"{action}.toml")
        assert {s.action for s in scene.script} == {action}
        assert not scene.effects
    every = load_scene(SCENES / "all-actions.toml")
    assert {s.action for s in every.script} == set(exercises)
    assert set(np.unique(build_motion(every).action)) == {NO_ACTION, *range(len(ACTIONS))}


def test_demo_scene_covers_all_actions_for_a_few_minutes_with_light_effects() -> None:
    scene = load_scene(SCENES / "demo.toml")
    motion = build_motion(scene)
    assert 120.0 <= len(motion) / motion.rate_hz <= 600.0
    assert set(np.unique(motion.action)) == {NO_ACTION, *range(len(ACTIONS))}
    assert {e["name"] for e in scene.effects} >= {"noise"}


def test_subjects_cover_a_realistic_range_and_repeat_from_a_seed() -> None:
    subjects = draw_subjects(200, seed=1)
    heights = np.array([s.height_m for s in subjects])
    bmi = np.array([s.mass_kg / s.height_m**2 for s in subjects])
    assert HEIGHT_RANGE_M[0] <= heights.min()
    assert heights.max() <= HEIGHT_RANGE_M[1]
    assert heights.min() < 1.60
    assert heights.max() > 1.85
    assert BMI_RANGE[0] - 0.1 <= bmi.min()
    assert bmi.max() <= BMI_RANGE[1] + 0.1
    feet = np.array([s.foot_length / s.height_m for s in subjects])
    assert feet.min() > 0.135
    assert feet.max() < 0.17
    assert len({s.style_seed for s in subjects}) == 200
    assert draw_subjects(200, seed=1) == subjects
    assert draw_subjects(5, seed=2) != subjects[:5]
    cadences = np.array([s.cadence_spm for s in subjects])
    assert TYPICAL_CADENCE_SPM[0] <= cadences.min()  # the drawn population walks briskly
    assert cadences.max() <= TYPICAL_CADENCE_SPM[1]
