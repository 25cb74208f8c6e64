"""Touch-downs from the keypoints, and the stepping actions' repetitions cut there."""

from __future__ import annotations

import itertools

import numpy as np
import numpy.typing as npt
import pytest
from scotti.models.contract import ACTIONS, FRAME_RATE_HZ, KP, NUM_KEYPOINTS
from scotti.models.errors import ModelInputError
from scotti.models.progress import (
    PeakParams,
    label_progress,
    progress_from_indicator,
    progress_indicator,
)
from scotti.models.touchdown import (
    DOWN_M,
    FOOT_POINTS,
    SEEN_AFTER,
    TOUCHDOWN_CUT,
    feet_down,
    step_starts,
    touchdowns,
)
from scotti.sim.actions import Context
from scotti.sim.motion import labels
from scotti.sim.scene import ScriptEntry, SubjectModel, motion_from_segments, script_segments

A = {name: i for i, name in enumerate(ACTIONS)}
AFTER_LANDING = PeakParams(step_cut="after_landing")
PEAK = PeakParams(step_cut="peak")
SWING, SUPPORT = 6, 3  # frames a foot is in the air, and both feet down between steps


def stepping(steps: int, lift: float = 0.08) -> tuple[npt.NDArray[np.float64], list[int]]:
    """Feet that step in turn (a half-sine of ``lift`` over SWING frames, SUPPORT frames
    of double support between), and the frames where each swing lands."""
    n = SUPPORT + steps * (SWING + SUPPORT)
    k = np.zeros((n, NUM_KEYPOINTS, 3))
    k[:, :, 2] = np.linspace(0.02, 1.7, NUM_KEYPOINTS)
    for points in FOOT_POINTS:
        k[:, list(points), 2] = 0.03  # every foot point rests 3 cm up (heel bone, toes)
    arc = lift * np.sin(np.pi * (np.arange(SWING) + 0.5) / SWING)
    landings = []
    for step in range(steps):
        at = SUPPORT + step * (SWING + SUPPORT)
        k[at : at + SWING, list(FOOT_POINTS[step % 2]), 2] += arc[:, None]
        landings.append(at + SWING)
    return k, [a for a in landings if a < n]


def test_a_landing_is_the_first_frame_a_foot_is_back_down() -> None:
    k, landings = stepping(6)
    np.testing.assert_array_equal(touchdowns(k, min_distance=2), landings)


def test_jitter_below_the_hysteresis_makes_no_landing() -> None:
    k, landings = stepping(6)
    # +-2 mm of noise on every foot point (motion capture's is about 1 mm): a
    # standing foot stays within DOWN_M of its rest and never rises past UP_M, so
    # it does not "land" again.
    noise = np.random.default_rng(3).uniform(-0.002, 0.002, size=(len(k), 6))
    points = [p for foot in FOOT_POINTS for p in foot]
    k[:, points, 2] += noise
    assert 2 * np.abs(noise).max() < DOWN_M
    np.testing.assert_array_equal(touchdowns(k, min_distance=2), landings)


def test_a_foot_that_never_leaves_the_floor_never_lands() -> None:
    k, _ = stepping(6, lift=0.008)  # 8 mm: between DOWN_M and UP_M, never "up"
    assert touchdowns(k, min_distance=2).size == 0


def test_masked_foot_points_read_nothing() -> None:
    k, _ = stepping(4)
    k[5, KP["left_heel"], 2] = np.nan
    assert feet_down(k) is None
    assert touchdowns(k, min_distance=2) is None


def test_a_step_starts_on_the_first_frame_whose_input_shows_its_landing() -> None:
    # The model predicts frame t from frames up to t - 1: frame L + 1 is the first
    # whose input holds a landing at L. A landing on the run's last frame starts no step.
    k, landings = stepping(6)
    assert SEEN_AFTER == 1
    np.testing.assert_array_equal(step_starts(k, min_distance=2), np.array(landings) + 1)
    cut_short = k[: landings[-1] + 1]
    np.testing.assert_array_equal(
        step_starts(cut_short, min_distance=2), np.array(landings[:-1]) + 1
    )


def test_walking_steps_start_at_0_after_each_landing_and_never_fall() -> None:
    k, landings = stepping(8)
    n = len(k)
    # The walking indicator (heel distance) peaks mid-support, not at the landing.
    k[:, KP["left_heel"], 0] = 0.2 * np.cos(2 * np.pi * np.arange(n) / (SWING + SUPPORT))
    labels_ = label_progress(k, np.full(n, A["walking"]), AFTER_LANDING)
    at_peaks = label_progress(k, np.full(n, A["walking"]), PEAK)
    peaks, _ = progress_from_indicator(progress_indicator(k, A["walking"]))
    np.testing.assert_allclose(at_peaks.progress, peaks.astype(np.float32))
    cuts = np.flatnonzero(np.diff(labels_.repetition) > 0) + 1
    np.testing.assert_array_equal(cuts, [a + SEEN_AFTER for a in landings if a + 1 < n])
    np.testing.assert_allclose(labels_.progress[cuts], 0.0, atol=1e-6)
    assert np.all(labels_.progress[cuts - 1] > 0.9)  # the landing frame ends its step
    for start, end in itertools.pairwise(cuts):
        step = labels_.progress[start:end]
        assert np.all(np.diff(step) >= 0), step
        assert step[-1] > 0.5  # the step runs on towards 1 up to the next landing


def test_actions_outside_the_stepping_set_keep_the_indicators_cuts() -> None:
    k, _ = stepping(8)
    k[:, KP["left_heel"], 0] = 0.2 * np.cos(2 * np.pi * np.arange(len(k)) / 7.0)
    side = A["side_walking"]
    assert side not in TOUCHDOWN_CUT
    got = label_progress(k, np.full(len(k), side), AFTER_LANDING)
    want, _ = progress_from_indicator(progress_indicator(k, side))
    np.testing.assert_allclose(got.progress, want.astype(np.float32))


def test_an_unknown_step_cut_is_refused() -> None:
    k, _ = stepping(4)
    with pytest.raises(ModelInputError, match="step_cut"):
        label_progress(k, np.full(len(k), A["walking"]), PeakParams(step_cut="landing"))


@pytest.mark.parametrize("action", ["walking", "backward_walking", "in_place_walking"])
def test_simulated_steps_are_cut_where_a_foot_lands(action: str) -> None:
    """A simulated walk: every repetition of the stepping action starts the frame after
    a landing, at progress 0, and the landings are about one per step."""
    subject = SubjectModel(height_m=1.75, mass_kg=72.0, style_seed=5).subject()
    ctx = Context(subject.body(), subject, FRAME_RATE_HZ, np.random.default_rng(2))
    segments = script_segments(ctx, [ScriptEntry(action=action, reps=12)])
    motion = motion_from_segments(ctx.body, ctx.subject, ctx.rate_hz, segments)
    truth = labels(motion)
    cut = label_progress(truth.keypoints, truth.action, AFTER_LANDING)
    a = A[action]
    run = np.flatnonzero(truth.action == a)
    start, end = int(run[0]), int(run[-1]) + 1
    assert run.size == end - start  # one run of the action
    rep = cut.repetition[start:end]
    cuts = np.flatnonzero(np.diff(rep) > 0) + 1
    landed = touchdowns(truth.keypoints[start:end], min_distance=4)
    assert landed is not None
    np.testing.assert_array_equal(cuts, landed[landed + 1 < end - start] + 1)
    assert cuts.size >= 8
    np.testing.assert_allclose(cut.progress[start:end][cuts], 0.0, atol=1e-6)
