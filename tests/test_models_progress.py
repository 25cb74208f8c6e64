"""Progress labelling: the paper's indicators and formula, and the hard cases."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from scotti.models.contract import ACTIONS, KP, NO_ACTION, NUM_ACTIONS, NUM_KEYPOINTS
from scotti.models.errors import ModelInputError
from scotti.models.progress import (
    PeakParams,
    find_peaks,
    label_progress,
    progress_from_indicator,
    progress_indicator,
    repetition_cuts,
)

A = {name: i for i, name in enumerate(ACTIONS)}
PERIOD = 32  # frames per repetition (2 s at 16 Hz)


def standing(n: int) -> npt.NDArray[np.float64]:
    """n frames of a still pose with distinct, plausible joint heights."""
    heights = np.linspace(0.0, 1.7, NUM_KEYPOINTS)
    k = np.zeros((n, NUM_KEYPOINTS, 3))
    k[:, :, 2] = heights
    k[:, :, 1] = np.where(np.arange(NUM_KEYPOINTS) % 2 == 1, 0.1, -0.1)
    return k


def with_hip_z(z: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    k = standing(len(z))
    k[:, KP["left_hip"], 2] = z + 0.01
    k[:, KP["right_hip"], 2] = z - 0.01
    return k


def cosine_truth(t: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Paper formula for h = cos(2 pi t / P): top at t = kP, bottom at kP + P/2."""
    phase = np.mod(t, PERIOD) / PERIOD * 2 * np.pi
    h = np.cos(phase)
    return np.where(phase <= np.pi, 0.5 * (1 - h) / 2, 0.5 + 0.5 * (h + 1) / 2)


def test_indicators_follow_the_paper_with_our_signs() -> None:
    n = 12
    k = standing(n)
    rng = np.random.default_rng(0)
    k += rng.normal(0, 0.05, k.shape)
    mid_hip_z = 0.5 * (k[:, KP["left_hip"], 2] + k[:, KP["right_hip"], 2])
    lh, rh = k[:, KP["left_heel"]], k[:, KP["right_heel"]]
    for name in ("squat", "lunge"):
        np.testing.assert_allclose(progress_indicator(k, A[name]), mid_hip_z)
    for name in ("jump", "step_up"):  # they rest at the bottom of the hip height
        np.testing.assert_allclose(progress_indicator(k, A[name]), -mid_hip_z)
    for name in ("walking", "side_walking"):
        np.testing.assert_allclose(progress_indicator(k, A[name]), np.linalg.norm(lh - rh, axis=1))
    # Walking in place is cut with both feet down: minus the higher heel's height.
    np.testing.assert_allclose(
        progress_indicator(k, A["in_place_walking"]), -np.maximum(lh[:, 2], rh[:, 2])
    )
    back = progress_indicator(k, A["backward_walking"])
    t = 8
    expected = max(np.linalg.norm(lh[t] - lh[t - 5]), np.linalg.norm(rh[t] - rh[t - 5]))
    assert back[t] == pytest.approx(expected)
    # The first frames compare with frame 0, the oldest available.
    expected_2 = max(np.linalg.norm(lh[2] - lh[0]), np.linalg.norm(rh[2] - rh[0]))
    assert back[2] == pytest.approx(expected_2)
    assert back[0] == 0.0


def test_step_ups_from_the_floor_count_once_each_and_peak_on_the_step() -> None:
    # K step-ups: floor pause, up onto a 0.2 m step, stand, back down.
    reps, period = 4, 48
    t = np.arange(reps * period + 8, dtype=np.float64)
    phase = np.mod(t - 8, period) / period
    on_step = np.where(t < 8, 0.0, np.clip(np.sin(np.pi * phase) * 1.6, 0.0, 1.0))
    labels = label_progress(with_hip_z(0.9 + 0.2 * on_step), np.full(len(t), A["step_up"]))
    assert int(labels.repetition.max()) + 1 == reps
    top = np.flatnonzero(on_step[: period + 8] == 1.0)
    assert labels.progress[top[len(top) // 2]] == pytest.approx(0.5, abs=0.05)


def test_indicator_refuses_no_action_standing_and_bad_shapes() -> None:
    with pytest.raises(ModelInputError, match="no progress indicator"):
        progress_indicator(standing(3), NO_ACTION)
    with pytest.raises(ModelInputError, match="action standing has no progress indicator"):
        progress_indicator(standing(3), A["standing"])
    with pytest.raises(ModelInputError, match=r"\(N, 19, 3\)"):
        progress_indicator(np.zeros((3, 17, 3)), 0)


def test_clean_squats_match_the_formula_including_partial_ends() -> None:
    # Starts a quarter into a repetition and ends in the descent of the last one.
    t = np.arange(PERIOD // 4, 4 * PERIOD + PERIOD // 3, dtype=np.float64)
    k = with_hip_z(0.9 + 0.2 * np.cos(2 * np.pi * t / PERIOD))
    labels = label_progress(k, np.full(len(t), A["squat"]))
    np.testing.assert_allclose(labels.progress, cosine_truth(t), atol=1e-6)
    # Cuts at the tops: t = 32, 64, 96, 128 -> repetitions 0..4.
    expected_rep = np.floor_divide(t.astype(int), PERIOD)
    np.testing.assert_array_equal(labels.repetition, expected_rep)
    assert labels.progress.dtype == np.float32
    assert labels.repetition.dtype == np.int32


def test_run_that_starts_and_ends_at_the_top_is_all_complete_repetitions() -> None:
    t = np.arange(0, 3 * PERIOD + 1, dtype=np.float64)
    h = np.cos(2 * np.pi * t / PERIOD)
    progress, repetition = progress_from_indicator(h)
    np.testing.assert_allclose(progress[:-1], cosine_truth(t)[:-1], atol=1e-9)
    assert progress[0] == 0.0
    assert progress[-1] == 1.0  # the run's last frame ends a repetition, no new one
    assert repetition.tolist() == [0] * 32 + [1] * 32 + [2] * 33


def test_shallower_partial_repetition_uses_its_own_bottom() -> None:
    # First repetition (partial, run starts at its top) is shallower than the rest.
    t = np.arange(0, 3 * PERIOD, dtype=np.float64)
    depth = np.where(t < PERIOD, 0.5, 1.0)
    h = depth * np.cos(2 * np.pi * t / PERIOD) + (1 - depth)
    progress, _ = progress_from_indicator(h)
    bottom = PERIOD // 2
    assert progress[bottom] == pytest.approx(0.5)
    assert np.all(np.diff(progress[:PERIOD]) >= 0)  # no jump around the bottom


def test_noisy_peaks_still_cut_once_per_repetition() -> None:
    rng = np.random.default_rng(3)
    t = np.arange(0, 6 * PERIOD, dtype=np.float64)
    clean = 0.9 + 0.2 * np.cos(2 * np.pi * t / PERIOD)
    noisy = clean + rng.normal(0, 0.004, t.size)
    cuts = repetition_cuts(noisy)
    np.testing.assert_allclose(cuts, [32, 64, 96, 128, 160], atol=3)
    progress, repetition = progress_from_indicator(noisy)
    assert repetition.max() == 5
    assert np.mean(np.abs(progress - cosine_truth(t))) < 0.05


def squats_with_pauses(pause: int) -> tuple[npt.NDArray[np.float64], list[int]]:
    """Three cosine squats, each followed by ``pause`` frames standing tall (with 1 mm sway)."""
    rep = 0.9 + 0.2 * np.cos(2 * np.pi * np.arange(PERIOD) / PERIOD)
    sway = 0.001 * np.sin(np.arange(pause))
    parts, arrivals, at = [np.full(6, 1.1)], [], 6
    for _ in range(3):
        parts += [rep[1:], 1.1 + sway]
        at += PERIOD - 1
        arrivals.append(at)  # first frame of the pause: back at the top
        at += pause
    return np.concatenate(parts), arrivals


def test_every_rest_at_the_top_belongs_to_the_next_repetition() -> None:
    # Cut where the person arrives at the top, not in the pause's middle: the
    # pause reads ~0 throughout (nothing in the input tells one half from the other).
    # The rest after the third squat, which ends the run, is cut like the two before
    # it instead of reading 1 to the end of the run.
    h, arrivals = squats_with_pauses(pause=20)
    cuts = repetition_cuts(h)
    # Up to two frames early: the last frames of the rise are within 8 % of the top.
    assert cuts.size == 3
    assert all(a - 2 <= c <= a for c, a in zip(cuts, arrivals, strict=True)), cuts
    progress, repetition = progress_from_indicator(h)
    for cut in cuts:
        pause = progress[cut : cut + 20]
        assert pause.size == 20
        assert pause.max() < 0.05, pause
        assert progress[cut - 1] > 0.85  # the repetition ran to its end: complete on arrival
        assert repetition[cut] == repetition[cut - 1] + 1
    assert repetition[-1] == 3


def test_a_rest_that_settles_low_is_cut_once_where_it_begins() -> None:
    # Back on the floor after a step-up the hips settle a little low (5 % of the
    # movement) and come up again just before the next repetition: the whole rest
    # belongs to the next repetition, not its first part to the last one.
    h, arrivals = squats_with_pauses(pause=24)
    for arrival in arrivals:
        h[arrival : arrival + 18] -= 0.05 * (h.max() - h.min())
    cuts = repetition_cuts(h)
    assert cuts.size == 3, cuts
    progress, _ = progress_from_indicator(h)
    for arrival in arrivals:
        assert progress[arrival : arrival + 24].max() < 0.15, progress[arrival : arrival + 24]


def test_a_single_repetition_then_a_rest_reads_zero_in_the_rest() -> None:
    h, arrivals = squats_with_pauses(pause=20)
    one = h[: arrivals[0] + 20]  # the first squat and the rest after it
    progress, repetition = progress_from_indicator(one)
    assert progress[arrivals[0] + 1 :].max() < 0.05, progress[arrivals[0] :]
    assert repetition[-1] == 1


def test_a_run_that_ends_rising_or_at_the_bottom_has_no_final_cut() -> None:
    h, arrivals = squats_with_pauses(pause=20)
    rising = h[: arrivals[2] - 3]  # ends three frames before the top
    assert repetition_cuts(rising).tolist() == repetition_cuts(h)[:2].tolist()
    bottom = h[: arrivals[1] + 20 + PERIOD // 2]  # ends in the bottom of the third squat
    bottom = np.r_[bottom, np.full(10, bottom[-1])]
    assert repetition_cuts(bottom).tolist() == repetition_cuts(h)[:2].tolist()


def test_walking_in_place_is_cut_with_both_feet_down() -> None:
    # Heels lift in turn (a half-sine of 0.1 m over 6 frames), 3 frames of double
    # support between: every cut falls in a double support, every mid-swing at ~0.5.
    swing, support, steps = 6, 3, 8
    lift = 0.1 * np.sin(np.pi * (np.arange(swing) + 0.5) / swing)
    n = steps * (swing + support) + support
    k = standing(n)
    left, right = np.zeros(n), np.zeros(n)
    for step in range(steps):
        at = support + step * (swing + support)
        (left if step % 2 == 0 else right)[at : at + swing] = lift
    k[:, KP["left_heel"], 2], k[:, KP["right_heel"], 2] = left, right
    labels = label_progress(k, np.full(n, A["in_place_walking"]))
    cuts = np.flatnonzero(np.diff(labels.repetition) > 0) + 1
    assert cuts.size >= steps - 1
    assert np.all(np.maximum(left, right)[cuts] == 0.0), cuts  # both feet down at each cut
    tops = [support + s * (swing + support) + swing // 2 for s in range(1, steps - 1)]
    np.testing.assert_allclose(labels.progress[tops], 0.5, atol=0.1)


def test_a_short_smooth_top_is_no_pause() -> None:
    # Without a rest the cut stays at the peak: the frame before it still ends the repetition.
    h, _ = squats_with_pauses(pause=0)
    cuts = repetition_cuts(h)
    smooth_peaks = find_peaks(h, min_prominence=0.1)
    np.testing.assert_array_equal(cuts, smooth_peaks)


def test_fast_walking_steps_are_separate_repetitions() -> None:
    # Heel distance peaks every 8 frames (two steps per second).
    n = 64
    t = np.arange(n, dtype=np.float64)
    k = standing(n)
    stride = 0.3 * np.abs(np.sin(np.pi * t / 8)) + 0.05
    k[:, KP["left_heel"], 0] = stride / 2
    k[:, KP["right_heel"], 0] = -stride / 2
    k[:, KP["left_heel"], 1] = k[:, KP["right_heel"], 1] = 0.0
    labels = label_progress(k, np.full(n, A["walking"]))
    assert labels.repetition.max() == 8  # peaks at 4, 12, ..., 60
    assert np.all(np.isfinite(labels.progress))


def test_flat_indicator_gives_half_everywhere() -> None:
    progress, repetition = progress_from_indicator(np.full(50, 0.8))
    np.testing.assert_array_equal(progress, 0.5)
    np.testing.assert_array_equal(repetition, 0)
    # Noise far below a millimetre is still flat: no repetition is invented.
    wiggle = 0.8 + np.random.default_rng(1).normal(0, 1e-5, 50)
    _, repetition = progress_from_indicator(wiggle)
    np.testing.assert_array_equal(repetition, 0)


def test_single_frame_and_empty_runs() -> None:
    labels = label_progress(standing(1), np.array([A["jump"]]))
    assert labels.progress.tolist() == [0.5]
    assert labels.repetition.tolist() == [0]
    empty = label_progress(np.zeros((0, NUM_KEYPOINTS, 3)), np.zeros(0, dtype=np.int64))
    assert empty.progress.shape == (0,)
    assert empty.repetition.shape == (0,)


def test_nan_keypoints_give_finite_progress() -> None:
    t = np.arange(3 * PERIOD, dtype=np.float64)
    k = with_hip_z(0.9 + 0.2 * np.cos(2 * np.pi * t / PERIOD))
    k[10:14] = np.nan
    k[-1] = np.inf
    labels = label_progress(k, np.full(len(t), A["squat"]))
    assert np.all(np.isfinite(labels.progress))
    all_nan = label_progress(np.full((5, NUM_KEYPOINTS, 3), np.nan), np.zeros(5, dtype=int))
    np.testing.assert_array_equal(all_nan.progress, 0.5)


def test_runs_of_actions_and_stands() -> None:
    t = np.arange(2 * PERIOD, dtype=np.float64)
    squat = with_hip_z(0.9 + 0.2 * np.cos(2 * np.pi * t / PERIOD))
    k = np.concatenate([standing(5), squat, standing(3), squat])
    actions = np.concatenate(
        [
            np.full(5, NO_ACTION),
            np.full(len(t), A["squat"]),
            np.full(3, NO_ACTION),
            np.full(len(t), A["lunge"]),
        ]
    )
    labels = label_progress(k, actions)
    stands = actions == NO_ACTION
    assert np.all(np.isnan(labels.progress[stands]))
    assert np.all(labels.repetition[stands] == -1)
    assert np.all(np.isfinite(labels.progress[~stands]))
    # Each run counts its repetitions from 0.
    first = labels.repetition[5 : 5 + len(t)]
    second = labels.repetition[-len(t) :]
    np.testing.assert_array_equal(first, second)
    assert first[0] == 0
    assert first.max() == 1


def test_standing_has_no_progress_and_no_repetition() -> None:
    """Standing frames, even with the body swaying like a shallow squat, get NaN and -1."""
    t = np.arange(2 * PERIOD, dtype=np.float64)
    squat = with_hip_z(0.9 + 0.2 * np.cos(2 * np.pi * t / PERIOD))
    sway = with_hip_z(0.9 + 0.01 * np.cos(2 * np.pi * t / PERIOD))
    k = np.concatenate([sway, squat, sway])
    still, squatting = np.full(len(t), A["standing"]), np.full(len(t), A["squat"])
    actions = np.concatenate([still, squatting, still])
    labels = label_progress(k, actions)
    stood = actions == A["standing"]
    assert np.all(np.isnan(labels.progress[stood]))
    assert np.all(labels.repetition[stood] == -1)
    assert np.all(np.isfinite(labels.progress[~stood]))
    assert labels.repetition[~stood].max() == 1  # the squat between still counts from 0


def test_label_progress_refuses_bad_actions() -> None:
    with pytest.raises(ModelInputError, match="neither NO_ACTION"):
        label_progress(standing(3), np.array([0, NUM_ACTIONS, 0]))
    with pytest.raises(ModelInputError, match="actions must be"):
        label_progress(standing(3), np.array([0.0, 1.0, 0.0]))
    with pytest.raises(ModelInputError, match="actions must be"):
        label_progress(standing(3), np.array([0, 1]))


def test_find_peaks_plateaus_borders_prominence_and_distance() -> None:
    # Plateau 2..4 -> its middle 3; the border samples are never peaks.
    assert find_peaks([0, 1, 5, 5, 5, 1, 9]).tolist() == [3]
    assert find_peaks([9, 1, 0]).tolist() == []
    # Small bump (prominence 1) beside a big one (prominence 8).
    x = [0, 8, 0, 1, 0.5, 1.5, 0]
    assert find_peaks(x).tolist() == [1, 3, 5]
    assert find_peaks(x, min_prominence=1.2).tolist() == [1, 5]
    assert find_peaks(x, min_prominence=2.0).tolist() == [1]
    # Distance keeps the higher of two near peaks.
    assert find_peaks([0, 3, 0, 5, 0, 0, 0, 4, 0], min_distance=3).tolist() == [3, 7]


def test_peak_params_are_honoured() -> None:
    t = np.arange(0, 4 * PERIOD, dtype=np.float64)
    h = np.cos(2 * np.pi * t / PERIOD)
    assert repetition_cuts(h, PeakParams(min_distance=40)).size == 2  # every other top
    assert repetition_cuts(h, PeakParams(abs_prominence=3.0)).size == 0


@settings(max_examples=60, deadline=None)
@given(
    hnp.arrays(
        np.float64,
        st.integers(0, 120),
        elements=st.floats(allow_nan=True, allow_infinity=True, width=64),
    )
)
def test_any_indicator_gives_finite_progress_in_range(h: npt.NDArray[np.float64]) -> None:
    progress, repetition = progress_from_indicator(np.clip(h, -1e6, 1e6))
    assert progress.shape == repetition.shape == h.shape
    assert np.all(np.isfinite(progress))
    assert np.all((progress >= 0) & (progress <= 1))
    if h.size:
        assert repetition[0] == 0
        assert set(np.diff(repetition).tolist()) <= {0, 1}
