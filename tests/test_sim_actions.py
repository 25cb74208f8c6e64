"""Action recipes: feet on the floor, squat depth, gait timing, flight, step height, labels."""

from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np
import pytest
from scotti.models.contract import ACTIONS, BONE_INDEX, KP, NO_ACTION, STANDING
from scotti.sim.actions import RECIPES, ActionSpec, Context, Place
from scotti.sim.actions.base import finalize, neutral
from scotti.sim.actions.gait import STANCE, stance_share
from scotti.sim.actions.strength import SQUAT_DROP
from scotti.sim.motion import Motion, Subject, labels
from scotti.sim.scene import Scene, build_motion, motion_from_segments
from scotti.sim.skeleton import Body, pose_keypoints

FOOT_POINTS = [f"{s}_{p}" for s in ("left", "right") for p in ("heel", "big_toe", "small_toe")]
HEIGHT = 1.75


def _motion(
    action: str,
    rate: float = 16.0,
    seed: int = 0,
    given: dict[str, float | str] | None = None,
    **spec: object,
) -> Motion:
    subject = Subject(HEIGHT, 70.0, style_seed=7, traits_given=given or {})
    body = Body.from_height(HEIGHT, subject.foot_length)
    ctx = Context(body, subject, rate, np.random.default_rng(seed))
    params = {"reps": 4, **spec}
    segment = RECIPES[action](ctx, ActionSpec(action, **params), Place(0.0, 0.0, 0.0))  # type: ignore[arg-type]
    return motion_from_segments(body, subject, rate, [segment])


def _feet_z(m: Motion) -> np.ndarray:
    return m.world[:, [KP[n] for n in FOOT_POINTS], 2]


def _mid_hip(m: Motion) -> np.ndarray:
    return np.asarray(0.5 * (m.world[:, KP["left_hip"]] + m.world[:, KP["right_hip"]]))


def _contact(m: Motion, side: str) -> np.ndarray:
    z = m.world[:, [KP[f"{side}_heel"], KP[f"{side}_big_toe"], KP[f"{side}_small_toe"]], 2]
    return np.asarray(z.min(axis=1) < 0.005)


@pytest.mark.parametrize("action", ACTIONS)
def test_every_action_keeps_feet_above_floor_and_moves_smoothly(action: str) -> None:
    m = _motion(action, rate=64.0)
    assert (_feet_z(m) >= -1e-3).all()
    bones = np.linalg.norm(m.world[:, BONE_INDEX[:, 0]] - m.world[:, BONE_INDEX[:, 1]], axis=-1)
    assert np.ptp(bones, axis=0).max() < 1e-3  # every contract bone keeps its length
    assert np.isfinite(m.world).all()
    assert np.isfinite(m.com).all()
    # No teleporting: no keypoint faster than a sprinting foot (8 m/s).
    speed = np.linalg.norm(np.diff(m.world, axis=0), axis=-1) * m.rate_hz
    assert speed.max() < 8.0
    # Starts and ends in the neutral stand (how segments join without a jump).
    body = Body.from_height(HEIGHT, m.subject.foot_length)
    start = pose_keypoints(body, finalize(body, neutral(body, Place(0.0, 0.0, 0.0), 1)))[0]
    assert np.abs(m.world[0] - start).max() < 2e-3
    end = m.world[-1] - (_mid_hip(m)[-1] - _mid_hip(m)[0]) * np.array([1.0, 1.0, 0.0])
    assert np.abs(end - start).max() < 2e-3


@pytest.mark.parametrize("depth", [0.3, 0.9])
def test_squat_lowers_the_hips_by_depth_with_feet_fixed(depth: float) -> None:
    m = _motion("squat", depth=depth, reps=3)
    hip_z = _mid_hip(m)[:, 2]
    drop = hip_z[0] - hip_z.min()
    # The recipe drops the hips SQUAT_DROP x height at depth 1 (+-15 % per repetition).
    assert drop == pytest.approx(SQUAT_DROP * HEIGHT * depth, rel=0.2)
    feet = m.world[:, [KP[n] for n in FOOT_POINTS]]
    assert np.ptp(feet, axis=0).max() < 1e-3  # feet stay where they are, heels down
    assert np.abs(feet[..., 2]).max() < 1e-3


def test_deeper_squat_goes_lower() -> None:
    shallow = _mid_hip(_motion("squat", depth=0.3))[:, 2].min()
    deep = _mid_hip(_motion("squat", depth=0.9))[:, 2].min()
    assert deep < shallow - 0.15


def _strikes_and_stance_shares(m: Motion) -> tuple[list[int], list[float]]:
    """Both feet's touch-down frames, and the stance share of each steady gait cycle."""
    strikes: list[int] = []
    stance_shares: list[float] = []
    for side in ("left", "right"):
        contact = _contact(m, side)
        onsets = np.flatnonzero(contact[1:] & ~contact[:-1]) + 1
        strikes += onsets.tolist()
        # Steady state: whole gait cycles between this foot's heel strikes.
        for a, b in itertools.pairwise(onsets[1:-1]):
            stance_shares.append(float(contact[a:b].mean()))
    return strikes, stance_shares


def test_walking_cadence_and_stance_fraction() -> None:
    m = _motion("walking", reps=16)
    subject = m.subject
    strikes, stance_shares = _strikes_and_stance_shares(m)
    strikes.sort()
    intervals = np.diff(strikes[1:-1]) / m.rate_hz  # steady steps, seconds
    cadence = 60.0 / intervals.mean()
    assert 100.0 * 0.9 < cadence < 120.0 * 1.1
    assert cadence == pytest.approx(subject.cadence_spm, rel=0.1)
    assert np.mean(stance_shares) == pytest.approx(0.6, abs=0.05)


def test_a_slow_walker_stands_longer_in_each_cycle() -> None:
    def stance(walking_speed_mps: float) -> tuple[float, float]:
        m = _motion("walking", given={"walking_speed_mps": walking_speed_mps}, reps=16)
        _, shares = _strikes_and_stance_shares(m)
        return m.subject.cadence_spm, float(np.mean(shares))

    typical_cadence, typical_share = stance(1.36)
    slow_cadence, slow_share = stance(0.55)
    assert slow_cadence < 75.0 < 95.0 < typical_cadence
    assert typical_share == pytest.approx(STANCE, abs=0.05)
    assert slow_share > typical_share + 0.04  # double support grows as walkers slow down
    assert stance_share(slow_cadence) > stance_share(typical_cadence) == STANCE


def test_faster_tempo_walks_with_a_higher_cadence() -> None:
    slow = _motion("walking", reps=10, tempo=0.9)
    fast = _motion("walking", reps=10, tempo=1.2)
    assert len(fast) < len(slow)


def test_jump_has_a_flight_phase_with_both_feet_off_the_floor() -> None:
    m = _motion("jump", reps=3, rate=32.0)
    airborne = np.asarray((_feet_z(m) > 0.02).all(axis=1))
    # Three separate flights, each a run of airborne frames.
    starts = np.flatnonzero(airborne[1:] & ~airborne[:-1])
    assert len(starts) == 3
    assert airborne.sum() / m.rate_hz > 3 * 0.2
    assert _mid_hip(m)[:, 2].max() > _mid_hip(m)[0, 2] + 0.1


@pytest.mark.parametrize("height", [0.15, 0.3])
def test_step_up_raises_a_foot_by_the_step_height(height: float) -> None:
    m = _motion("step_up", reps=2, step_height_m=height)
    heel_z = m.world[:, [KP["left_heel"], KP["right_heel"]], 2]
    # Standing on the step: a flat foot whose heel rests at the step height.
    on_step = np.abs(heel_z - height) < 1e-3
    assert on_step.any(axis=0).all()  # both feet stand on it
    assert m.ground_z is not None
    assert m.ground_z.max() == pytest.approx(height)
    np.testing.assert_allclose(heel_z[on_step], m.ground_z[on_step], atol=1e-3)
    assert _mid_hip(m)[:, 2].max() > _mid_hip(m)[0, 2] + 0.8 * height


def test_lunge_bends_the_front_knee_and_lifts_the_rear_heel() -> None:
    m = _motion("lunge", reps=2, depth=0.8)
    hip_z = _mid_hip(m)[:, 2]
    bottom = int(hip_z.argmin())
    assert hip_z[0] - hip_z[bottom] > 0.2
    heels = m.world[bottom, [KP["left_heel"], KP["right_heel"]]]
    rear = int(np.argmin(heels[:, 0]))
    assert heels[rear, 2] > 0.03  # rear heel up
    assert heels[1 - rear, 2] < 1e-3  # front heel down


# How many repetitions the skeleton-based labeller completes for ``reps`` in
# the script. Exact where the action starts and ends resting at a top of its
# indicator (the rest after the last repetition is cut like every other, so
# the last one completes too); the stepping actions start and end mid-step,
# a cut more or less at each end (see gait.py).
TOLERANCE = {
    "squat": 0,
    "lunge": 0,
    "jump": 0,
    "step_up": 0,
    "walking": 2,
    "backward_walking": 2,
    "side_walking": 2,
    "in_place_walking": 2,
}


@pytest.mark.parametrize("action", ACTIONS)
def test_labels_progress_in_range_and_repetitions_counted(action: str) -> None:
    reps = 5
    scene = Scene.model_validate(
        {
            "seed": 3,
            "subject": {"height_m": 1.7, "mass_kg": 65.0, "style_seed": 2},
            "script": [{"action": action, "reps": reps}],
        }
    )
    m = build_motion(scene)
    lab = labels(m)
    # The lead-in and the stand after the action are standing; jump's sink and rise
    # are transitions (NO_ACTION).
    assert set(np.unique(lab.action)) <= {ACTIONS.index(action), STANDING, NO_ACTION}
    assert (lab.action[: int(m.rate_hz)] == STANDING).all()
    if action == "standing":
        assert np.isnan(lab.progress).all()
        assert (lab.repetition == -1).all()
        return
    active = lab.action == ACTIONS.index(action)
    assert active.any()
    assert np.isfinite(lab.progress[active]).all()
    assert (lab.progress[active] >= 0.0).all()
    assert (lab.progress[active] <= 1.0).all()
    # Outside the action (standing, transitions) there is no progress.
    assert np.isnan(lab.progress[~active]).all()
    assert (lab.repetition[~active] == -1).all()
    # A repetition completes at a cut inside a run of the action (where the
    # daemon's counter counts); a jump set with pauses is one run per jump (the
    # stand between is NO_ACTION).
    inside = active[1:] & active[:-1] & (np.diff(lab.repetition) == 1)
    completed = int(inside.sum())
    assert abs(completed - reps) <= TOLERANCE[action], completed
    assert lab.keypoints.dtype == np.float32
    assert lab.keypoints.shape == (len(m), 19, 3)


def test_same_scene_and_seed_give_identical_arrays() -> None:
    raw = {
        "seed": 5,
        "subject": {"height_m": 1.8, "mass_kg": 80.0, "style_seed": 9},
        "script": [{"action": "walking", "reps": 6}, {"action": "squat", "reps": 2}],
    }
    a, b = (build_motion(Scene.model_validate(raw)) for _ in range(2))
    np.testing.assert_array_equal(a.world, b.world)
    np.testing.assert_array_equal(a.action, b.action)
    np.testing.assert_array_equal(a.com, b.com)
    other = build_motion(Scene.model_validate({**raw, "seed": 6}))
    assert other.world.shape != a.world.shape or not np.array_equal(other.world, a.world)


def test_transitions_blend_without_a_jump() -> None:
    scene = Scene.model_validate(
        {
            "subject": {"height_m": 1.7, "mass_kg": 60.0},
            "rate": 16.0,
            "script": [
                {"action": "walking", "reps": 4, "stand_s": 1.0},
                {"action": "squat", "reps": 2, "stand_s": 0.5},
                {"action": "side_walking", "reps": 2},
            ],
        }
    )
    m = build_motion(scene, oversample=4)
    assert m.rate_hz == 64.0
    step = np.linalg.norm(np.diff(m.world, axis=0), axis=-1).max(axis=1)
    changes = np.flatnonzero(np.diff(m.action) != 0)
    assert step[changes].max() < 0.02  # 2 cm in 1/64 s where the label changes
    assert (m.action[: int(m.rate_hz)] == STANDING).all()  # lead-in stand
    down = m.every(4)
    assert down.rate_hz == 16.0
    np.testing.assert_array_equal(down.world, m.world[::4])


# --- people who differ and variation within a set -------------------------------


def _person_motion(
    action: str, traits: dict[str, float | str], rate: float = 16.0, **spec: object
) -> Motion:
    """One segment by a person with some traits given (their own stance and toe-out)."""
    subject = Subject(HEIGHT, 70.0, style_seed=21, traits_given=traits)
    body = subject.body()
    ctx = Context(body, subject, rate, np.random.default_rng(1))
    segment = RECIPES[action](ctx, ActionSpec(action, **spec), Place(0.0, 0.0, 0.0))  # type: ignore[arg-type]
    return motion_from_segments(body, subject, rate, [segment])


@pytest.mark.parametrize("action", ACTIONS)
def test_every_action_starts_and_ends_in_the_persons_own_stand(action: str) -> None:
    traits: dict[str, float | str] = {
        "stance_width_m": 0.24,
        "toe_out_deg": 15.0,
        "toe_out_asymmetry_deg": 0.0,
    }
    m = _person_motion(action, traits, rate=32.0, reps=3, vary=True)
    body = m.subject.body()
    start = pose_keypoints(body, finalize(body, neutral(body, Place(0.0, 0.0, 0.0), 1)))[0]
    assert np.abs(m.world[0] - start).max() < 2e-3
    ankles = m.world[0, [KP["left_ankle"], KP["right_ankle"]]]
    assert ankles[0, 1] - ankles[1, 1] == pytest.approx(0.24, abs=0.005)
    # The feet turn out by 15 degrees more than a person with no toe-out.
    straight = _person_motion(action, {**traits, "toe_out_deg": 0.0}, rate=32.0, reps=1)
    for k in (0, -1):
        for side, sign in (("left", 1.0), ("right", -1.0)):
            turned, ahead = (
                x.world[k, KP[f"{side}_big_toe"], :2] - x.world[k, KP[f"{side}_heel"], :2]
                for x in (m, straight)
            )
            angle = (np.arctan2(turned[1], turned[0]) - m.heading[k]) - (
                np.arctan2(ahead[1], ahead[0]) - straight.heading[k]
            )
            assert sign * np.degrees(angle) == pytest.approx(15.0, abs=0.5)
    speed = np.linalg.norm(np.diff(m.world, axis=0), axis=-1) * m.rate_hz
    assert speed.max() < 8.0
    assert (_feet_z(m) >= -1e-3).all()


def _touch_down_pitch(m: Motion, side: str) -> np.ndarray:
    """Foot pitch (> 0 toes up) at each touch-down, from heel and big toe keypoints."""
    heel, toe = m.world[:, KP[f"{side}_heel"]], m.world[:, KP[f"{side}_big_toe"]]
    contact = _contact(m, side)
    onsets = np.flatnonzero(contact[1:] & ~contact[:-1]) + 1
    d = toe - heel
    pitch = np.arctan2(d[:, 2], np.linalg.norm(d[:, :2], axis=1))
    return np.asarray(pitch[onsets])


@pytest.mark.parametrize(
    ("strike", "low", "high"),
    [("heel", 0.2, 0.6), ("midfoot", -0.08, 0.12), ("forefoot", -0.4, -0.08)],
)
def test_strike_pattern_shows_in_foot_pitch_at_touch_down(
    strike: str, low: float, high: float
) -> None:
    m = _person_motion("walking", {"strike": strike}, rate=64.0, reps=8)
    pitches = np.r_[_touch_down_pitch(m, "left"), _touch_down_pitch(m, "right")]
    assert len(pitches) >= 6
    steady = np.sort(pitches)[1:-1]  # the closing step lands at half the angle
    assert low < np.median(steady) < high


def _toe_off_pitch(m: Motion, side: str) -> np.ndarray:
    """Foot pitch (< 0 toes down) on the last frame of each contact, as the foot leaves."""
    heel, toe = m.world[:, KP[f"{side}_heel"]], m.world[:, KP[f"{side}_big_toe"]]
    contact = _contact(m, side)
    offsets = np.flatnonzero(contact[:-1] & ~contact[1:])
    d = toe - heel
    pitch = np.arctan2(d[:, 2], np.linalg.norm(d[:, :2], axis=1))
    return np.asarray(pitch[offsets])


def test_push_off_scales_how_far_the_foot_rolls_over_its_toes_before_it_leaves() -> None:
    """A shuffler (push_off 0.2) lifts the heel a fifth as far at toe-off as the typical
    walker, whose foot leaves the floor pitched about 0.6 rad toes down."""
    pitches = {}
    for push_off in (1.0, 0.2):
        m = _person_motion("walking", {"push_off": push_off}, rate=64.0, reps=8)
        pitches[push_off] = np.r_[_toe_off_pitch(m, "left"), _toe_off_pitch(m, "right")]
        assert len(pitches[push_off]) >= 6
    typical, shuffle = np.median(pitches[1.0]), np.median(pitches[0.2])
    assert -0.7 < typical < -0.4
    assert shuffle == pytest.approx(0.2 * typical, abs=0.05)


def test_the_typical_population_pushes_off_alike_and_draws_as_before() -> None:
    """push_off is not drawn: every other trait of a seed is what it was without it."""
    plain = Subject(HEIGHT, 70.0, style_seed=5).traits
    given = Subject(HEIGHT, 70.0, style_seed=5, traits_given={"push_off": 0.3}).traits
    assert plain.push_off == 1.0
    assert given.push_off == 0.3
    assert replace(given, push_off=1.0) == plain


def test_a_walk_that_turns_changes_heading_and_labels_stay_in_the_persons_frame() -> None:
    m = _person_motion("walking", {}, reps=16, turn_rad=np.pi / 2)
    assert m.heading[-1] - m.heading[0] == pytest.approx(np.pi / 2, abs=1e-6)
    # The person ends up facing and having walked towards +y (a left turn).
    hip = _mid_hip(m)
    assert hip[-1, 1] > 2.0
    lab = labels(m)
    k = lab.keypoints
    # Pose frame: x forwards, y to the left, whatever the heading.
    assert (k[:, KP["left_hip"], 1] > 0.05).all()
    assert (k[:, KP["right_hip"], 1] < -0.05).all()
    for side in ("left", "right"):
        foot = k[:, KP[f"{side}_big_toe"], :2] - k[:, KP[f"{side}_heel"], :2]
        along = foot[:, 0] / np.linalg.norm(foot, axis=1)
        assert (along > 0.8).all()  # feet point forwards in the person's frame
    # Where the walk goes and where the person faces agree, start and end.
    moved = np.diff(hip[:, :2], axis=0)
    for i in (slice(16, 24), slice(-24, -16)):
        direction = np.arctan2(*moved[i].sum(axis=0)[::-1])
        assert direction == pytest.approx(m.heading[i].mean(), abs=0.25)


def test_speed_changes_vary_the_step_times_of_a_walk() -> None:
    traits: dict[str, float | str] = {"speed_variability": 0.1, "stride_cv": 0.01}

    def step_times(vary: bool) -> np.ndarray:
        m = _person_motion("walking", traits, rate=64.0, reps=40, vary=vary)
        onsets = []
        for side in ("left", "right"):
            contact = _contact(m, side)
            onsets += (np.flatnonzero(contact[1:] & ~contact[:-1]) + 1).tolist()
        return np.diff(np.sort(onsets))[2:-2] / m.rate_hz

    assert np.std(step_times(True)) > 2.0 * np.std(step_times(False))


def _reps(m: Motion) -> tuple[np.ndarray, np.ndarray]:
    """Frames and mid-hip drop of each complete repetition the labeller finds."""
    lab = labels(m)
    hip_z = _mid_hip(m)[:, 2]
    reps = np.unique(lab.repetition[lab.repetition >= 0])[1:-1]
    frames = np.array([np.count_nonzero(lab.repetition == r) for r in reps])
    drops = np.array([hip_z[0] - hip_z[lab.repetition == r].min() for r in reps])
    return frames, drops


@pytest.mark.parametrize("action", ["squat", "lunge"])
def test_fatigue_makes_late_repetitions_slower_and_shallower(action: str) -> None:
    traits: dict[str, float | str] = {
        "fatigue_slowdown_per_min": 0.08,
        "fatigue_shallowing_per_min": 0.05,
        "tempo_variation": 0.02,
        "depth_variation": 0.02,
        "rep_pause_s": 0.0,
        "squat_rep_s": 3.0,
        "lunge_rep_s": 3.5,
    }
    # 40 repetitions take over two minutes: the last ones about 15 % slower.
    frames, drops = _reps(_person_motion(action, traits, reps=40))
    assert frames[-6:].mean() > 1.08 * frames[:6].mean()
    assert drops[-6:].mean() < 0.92 * drops[:6].mean()


def test_pauses_between_repetitions_lengthen_a_set() -> None:
    base: dict[str, float | str] = {"tempo_variation": 0.02, "fatigue_slowdown_per_min": 0.02}
    quick = _person_motion("squat", {**base, "rep_pause_s": 0.0}, reps=10)
    paused = _person_motion("squat", {**base, "rep_pause_s": 1.5}, reps=10)
    assert (len(paused) - len(quick)) / quick.rate_hz > 5.0
    repetition = labels(paused).repetition
    completed = int(((np.diff(repetition) == 1) & (repetition[:-1] >= 0)).sum())
    assert completed == 10  # pauses are no repetitions
