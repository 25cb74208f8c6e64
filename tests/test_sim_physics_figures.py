"""The simulator's physics against people's: one test per claim, through the real scene pipeline.

Each builds a short scene at the internal rate (``PHYSICS_OVERSAMPLE`` x
16 Hz) and measures it with ``physics_figures.measure``; the ranges are
those in the module's table (and the sources cited there).
"""

from __future__ import annotations

import itertools
from functools import cache
from typing import Any

import numpy as np
import pytest
from scotti.models.contract import ACTIONS, KP, NO_ACTION
from scotti.sim.loads import G, foot_loads
from scotti.sim.motion import Motion, labels
from scotti.sim.physics_figures import PhysicsFigures, measure
from scotti.sim.scene import PHYSICS_OVERSAMPLE, Scene, build_motion
from scotti.sim.subjects import draw_subjects

SUBJECTS = [(1.58, 52.0, 4), (1.80, 85.0, 11)]


def _scene(action: str, reps: int, height: float, mass: float, style: int, **extra: Any) -> Scene:
    return Scene.model_validate(
        {
            "seed": style,
            "subject": {"height_m": height, "mass_kg": mass, "style_seed": style},
            "script": [{"action": action, "reps": reps, "stand_s": 1.0, **extra}],
        }
    )


@cache
def _motion(action: str, reps: int, subject: int = 0) -> Motion:
    return build_motion(_scene(action, reps, *SUBJECTS[subject]), PHYSICS_OVERSAMPLE)


@cache
def _figures(action: str, reps: int, subject: int = 0) -> PhysicsFigures:
    return measure(_motion(action, reps, subject))


@pytest.mark.parametrize("subject", range(len(SUBJECTS)))
def test_jump_lands_at_two_and_a_half_to_four_body_weights_and_flies_unloaded(
    subject: int,
) -> None:
    f = _figures("jump", 3, subject)
    assert f.rate_hz >= 128.0
    assert 2.5 <= f.jump_landing_peak_bw <= 4.0
    assert f.jump_flight_max_n == 0.0


def test_jump_landings_differ_between_left_and_right() -> None:
    m = _motion("jump", 3, 1)
    loads = foot_loads(m.world, m.com, m.rate_hz, m.subject.mass_kg, m.ground_z)
    bw = m.subject.mass_kg * G
    landing = loads.load_n.sum(axis=1) > 1.5 * bw
    difference = np.abs(loads.load_n[landing, 0] - loads.load_n[landing, 1]) / bw
    assert difference.max() > 0.05  # not mirror images
    f = _figures("jump", 3, 1)
    assert f.jump_touchdown_gap_ms > 0.0 or f.jump_split_difference > 0.01


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    edges = np.flatnonzero(np.diff(np.r_[0, mask.astype(np.int8), 0]))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))


def completed_repetitions(repetition: np.ndarray) -> int:
    """Repetitions the labels complete: a run's index steps up where the next one
    begins, at the rest that follows the last one too (models/progress.py)."""
    return int(((np.diff(repetition) == 1) & (repetition[:-1] >= 0)).sum())


def test_jump_sets_pause_standing_or_run_on_and_count_every_jump() -> None:
    runs_per_set = set()
    for seed in range(12):
        m = build_motion(_scene("jump", 3, 1.7, 65.0, seed))
        runs = _runs(m.action == ACTIONS.index("jump"))
        runs_per_set.add(len(runs))
        # Every jump completes one repetition, however the set is cut into runs.
        assert completed_repetitions(labels(m).repetition) == 3, seed
        # Paused: the stand between two jumps is NO_ACTION and lasts 0.5-2 s
        # (plus the rise after the landing and the sink before the next).
        for (_, end), (start, _) in itertools.pairwise(runs):
            assert 0.5 + 0.7 + 0.55 - 0.05 <= (start - end) / m.rate_hz <= 2.0 + 0.7 + 0.55 + 0.05
    assert runs_per_set == {1, 3}  # some sets continuous, some with a stand between jumps


@pytest.mark.parametrize("subject", range(len(SUBJECTS)))
def test_walking_has_the_double_hump(subject: int) -> None:
    f = _figures("walking", 8, subject)
    assert 1.1 <= f.walking_first_peak_bw <= 1.3
    assert 1.1 <= f.walking_second_peak_bw <= 1.3
    assert 0.65 <= f.walking_valley_bw <= 0.8


def test_centre_of_pressure_rolls_heel_to_toe_forwards_and_toe_first_backwards() -> None:
    forward = _figures("walking", 6)
    assert forward.walking_cop_onset_u < 0.3 < 0.7 < forward.walking_cop_offset_u
    backward = _figures("backward_walking", 6)
    # Toe first: the forefoot third of the strike index (Cavanagh & Lafortune 1980).
    assert backward.backward_cop_onset_u > 0.67 > 0.3 > backward.backward_cop_offset_u


def test_backward_walking_is_its_own_gait_not_forward_reversed() -> None:
    forward, backward = _motion("walking", 6), _motion("backward_walking", 6)
    step = {}
    for name, m in (("forward", forward), ("backward", backward)):
        heels = m.world[:, [KP["left_heel"], KP["right_heel"]], 0]
        step[name] = np.ptp(heels[m.action != NO_ACTION], axis=0).max()
    # Shorter steps, and the heel-strike transient of walking is gone: it lands on the toes.
    assert step["backward"] < step["forward"]
    loads = foot_loads(
        backward.world, backward.com, backward.rate_hz, backward.subject.mass_kg, backward.ground_z
    )
    assert loads.impact_n is not None
    walking = foot_loads(
        forward.world, forward.com, forward.rate_hz, forward.subject.mass_kg, forward.ground_z
    )
    assert walking.impact_n is not None
    assert loads.impact_n.max() < 0.5 * walking.impact_n.max()


def test_side_walking_moves_the_centre_of_pressure_the_way_it_goes() -> None:
    for direction in ("left", "right"):
        m = build_motion(
            _scene("side_walking", 3, *SUBJECTS[0], direction=direction), PHYSICS_OVERSAMPLE
        )
        assert measure(m).side_cop_with_travel > 0.65


def test_squat_moves_the_centre_of_pressure_towards_the_heels_as_it_deepens() -> None:
    m = _motion("squat", 2)
    loads = foot_loads(m.world, m.com, m.rate_hz, m.subject.mass_kg, m.ground_z)
    on = m.action == ACTIONS.index("squat")
    hip = m.world[on][:, [KP["left_hip"], KP["right_hip"]], 2].mean(axis=1)
    drop = hip.max() - hip
    cop = loads.cop_u[on].mean(axis=1)
    # Mean COP per quarter of the depth: strictly towards the heel (u = 0).
    bins = np.digitize(drop, np.linspace(0.0, drop.max(), 5)[1:-1])
    means = [cop[bins == b].mean() for b in range(4)]
    assert all(a > b for a, b in itertools.pairwise(means))
    assert means[0] - means[-1] > 0.05
    assert _figures("squat", 2).squat_cop_depth_correlation < -0.8


def test_squat_depth_shows_in_the_centre_of_pressure_through_the_whole_repetition() -> None:
    # Both feet flat: the COP follows the COM back past the walking floor of
    # 0.30 along the foot. Before, most people's COP sat on that floor for
    # most of each squat, and depth (hence progress) left no trace in the maps.
    for subject in draw_subjects(4, 1):
        scene = _scene("squat", 3, subject.height_m, subject.mass_kg, subject.style_seed)
        m = build_motion(scene, PHYSICS_OVERSAMPLE)
        loads = foot_loads(m.world, m.com, m.rate_hz, m.subject.mass_kg, m.ground_z)
        on = m.action == ACTIONS.index("squat")
        hip = m.world[on][:, [KP["left_hip"], KP["right_hip"]], 2].mean(axis=1)
        drop = hip.max() - hip
        moving = drop > 0.02
        cop = loads.cop_u[on].mean(axis=1)
        assert np.corrcoef(cop[moving], drop[moving])[0, 1] < -0.85, subject


@pytest.mark.parametrize("subject", range(len(SUBJECTS)))
def test_step_up_loads_the_leading_leg_with_1_3_to_1_5_body_weights(subject: int) -> None:
    assert 1.3 <= _figures("step_up", 2, subject).step_up_lead_peak_bw <= 1.5


@pytest.mark.parametrize("reps", [1, 3])
def test_step_ups_are_counted_as_many_as_were_made(reps: int) -> None:
    lab = labels(build_motion(_scene("step_up", reps, *SUBJECTS[1])))
    assert completed_repetitions(lab.repetition) == reps


def test_standing_com_is_four_to_six_centimetres_in_front_of_the_ankles() -> None:
    f = _figures("squat", 2)  # the lead-in and the closing stand
    assert 0.04 <= f.standing_com_ahead_m <= 0.06


def test_figures_of_a_motion_without_an_action_are_nan() -> None:
    f = _figures("squat", 2)
    assert np.isnan(f.jump_landing_peak_bw)
    assert np.isnan(f.walking_valley_bw)
    assert set(f.as_dict()) >= {"rate_hz", "jump_landing_peak_bw", "standing_com_ahead_m"}
