"""Task metrics against answers worked out by hand."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pytest
from scotti.models.contract import (
    BONES,
    JOINT_ANGLES,
    KP,
    NO_ACTION,
    NUM_ACTIONS,
    NUM_KEYPOINTS,
    STANDING,
)
from scotti.models.errors import ModelInputError
from scotti.models.metrics import (
    action_accuracy,
    app,
    confusion_matrix,
    joint_angles_deg,
    mpjae_deg,
    mpjpe_mm,
    precision_margin,
    progress_mse,
)


def poses(n: int, seed: int = 0) -> npt.NDArray[np.float64]:
    return np.random.default_rng(seed).normal(0, 0.3, (n, NUM_KEYPOINTS, 3))


def test_mpjpe_of_a_known_translation() -> None:
    true = poses(10)
    shifted = true + np.array([0.03, -0.04, 0.0])  # 5 cm at every joint
    assert mpjpe_mm(shifted, true) == pytest.approx(50.0)
    assert mpjpe_mm(true, true) == 0.0
    # A single pose works too; the mask leaves frames out.
    assert mpjpe_mm(shifted[0], true[0]) == pytest.approx(50.0)
    far = shifted.copy()
    far[3] += 10.0
    keep = np.ones(10, dtype=bool)
    keep[3] = False
    assert mpjpe_mm(far, true, keep) == pytest.approx(50.0)
    assert mpjpe_mm(far, true) > 1000.0


def test_mpjpe_refuses_mismatched_shapes() -> None:
    with pytest.raises(ModelInputError, match="poses must both be"):
        mpjpe_mm(poses(3), poses(4))
    with pytest.raises(ModelInputError, match="mask must have"):
        mpjpe_mm(poses(3), poses(3), np.ones(2, dtype=bool))


def test_joint_angles_of_a_right_angled_elbow() -> None:
    k = np.zeros((NUM_KEYPOINTS, 3))
    k[KP["left_shoulder"]] = [0, 0, 1.5]
    k[KP["left_elbow"]] = [0, 0, 1.2]
    k[KP["left_wrist"]] = [0.3, 0, 1.2]
    angles = joint_angles_deg(k)
    left_elbow = JOINT_ANGLES.index((0, 1))
    assert BONES[0] == ("left_shoulder", "left_elbow")
    assert angles[left_elbow] == pytest.approx(90.0)
    straight = k.copy()
    straight[KP["left_wrist"]] = [0, 0, 0.9]
    assert joint_angles_deg(straight)[left_elbow] == pytest.approx(0.0, abs=1e-6)


def test_mpjae_known_bend_and_zero_length_bones() -> None:
    true = poses(4, seed=1)
    assert mpjae_deg(true, true) == 0.0
    # Fold the left forearm back onto the upper arm: that angle changes, others do not.
    pred = true.copy()
    upper = true[:, KP["left_elbow"]] - true[:, KP["left_shoulder"]]
    pred[:, KP["left_wrist"]] = true[:, KP["left_elbow"]] - upper
    before = joint_angles_deg(true)[:, 0]
    expected = np.mean(np.abs(180.0 - before)) / len(JOINT_ANGLES)
    assert mpjae_deg(pred, true) == pytest.approx(expected)
    # All joints in one point: every bone has zero length, the error stays finite.
    collapsed = np.zeros_like(true)
    assert np.isfinite(mpjae_deg(collapsed, true))
    assert np.all(np.isfinite(joint_angles_deg(collapsed)))


def test_action_accuracy_ignores_unlabelled_frames() -> None:
    true = np.array([0, 1, 2, NO_ACTION, 3, NO_ACTION])
    pred = np.array([0, 1, 5, 4, 3, 7])
    assert action_accuracy(pred, true) == pytest.approx(3 / 4)
    assert np.isnan(action_accuracy(np.array([1]), np.array([NO_ACTION])))
    with pytest.raises(ModelInputError, match="argmax"):
        action_accuracy(np.array([0.2, 0.8]), np.array([0, 1]))


def test_hand_built_confusion_matrix() -> None:
    true = np.array([0, 0, 0, 1, 1, 7, NO_ACTION, 2, STANDING, STANDING])
    pred = np.array([0, 0, 1, 1, 7, 7, 3, 0, STANDING, 0])
    expected = np.zeros((NUM_ACTIONS, NUM_ACTIONS), dtype=np.int64)
    expected[0, 0] = 2
    expected[0, 1] = 1
    expected[1, 1] = 1
    expected[1, 7] = 1
    expected[7, 7] = 1
    expected[2, 0] = 1
    expected[STANDING, STANDING] = 1  # standing is a class like the others
    expected[STANDING, 0] = 1
    cm = confusion_matrix(pred, true)
    assert cm.shape == (9, 9) == (NUM_ACTIONS, NUM_ACTIONS)
    np.testing.assert_array_equal(cm, expected)
    assert cm.sum() == 9  # the NO_ACTION frame is left out
    assert np.trace(cm) / cm.sum() == pytest.approx(action_accuracy(pred, true))
    with pytest.raises(ModelInputError, match="predicted actions"):
        confusion_matrix(np.array([NUM_ACTIONS]), np.array([0]))


def test_progress_mse_ignores_nan_labels() -> None:
    true = np.array([0.0, 0.5, np.nan, 1.0])
    pred = np.array([0.1, 0.5, 0.9, 0.7])
    assert progress_mse(pred, true) == pytest.approx((0.01 + 0.0 + 0.09) / 3)
    assert progress_mse(true, true) == 0.0


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_app_is_one_minus_mean_absolute_error(seed: int) -> None:
    rng = np.random.default_rng(seed)
    true = rng.uniform(0, 1, 200)
    pred = np.clip(true + rng.normal(0, 0.2 * (seed + 1), 200), 0, 1)
    result = precision_margin(pred, true, num_margins=20001)
    assert result.app == pytest.approx(1 - np.mean(np.abs(pred - true)), abs=1e-12)
    # The sampled curve integrates to the same area.
    assert np.trapezoid(result.precision, result.margins) == pytest.approx(result.app, abs=1e-3)


def test_app_by_hand_and_with_errors_beyond_one() -> None:
    # Errors 0.1 and 0.3: area = 1 - 0.2.
    assert app(np.array([0.1, 0.7]), np.array([0.0, 1.0])) == pytest.approx(0.8)
    # An error of 2 (out of range predictions) counts as 1, never negative area.
    assert app(np.array([2.0, 0.5]), np.array([0.0, 0.5])) == pytest.approx(0.5)
    assert app(np.array([np.nan, 0.5]), np.array([0.0, 0.5])) == pytest.approx(0.5)


def test_app_curve_shape() -> None:
    true = np.array([0.0, 0.0, 0.0, 0.0, np.nan])
    pred = np.array([0.0, 0.25, 0.5, 1.0, 0.3])
    result = precision_margin(pred, true, num_margins=5)
    np.testing.assert_allclose(result.margins, [0, 0.25, 0.5, 0.75, 1.0])
    np.testing.assert_allclose(result.precision, [0.25, 0.5, 0.75, 0.75, 1.0])
    assert result.frames == 4
    assert np.all(np.diff(result.precision) >= 0)


def test_perfect_predictions() -> None:
    true = np.random.default_rng(5).uniform(0, 1, 100)
    assert app(true, true) == 1.0
    assert progress_mse(true, true) == 0.0
    assert precision_margin(true, true).precision[0] == 1.0


def test_chance_app_is_two_thirds() -> None:
    rng = np.random.default_rng(42)
    true = rng.uniform(0, 1, 100_000)
    pred = rng.uniform(0, 1, 100_000)
    assert app(pred, true) == pytest.approx(2 / 3, abs=0.005)


def test_no_labelled_progress_is_nan() -> None:
    result = precision_margin(np.array([0.5]), np.array([np.nan]))
    assert np.isnan(result.app)
    assert result.frames == 0
    assert np.isnan(progress_mse(np.array([0.5]), np.array([np.nan])))


def test_pose_metrics_leave_out_missing_keypoints_one_by_one() -> None:
    rng = np.random.default_rng(3)
    true = rng.normal(size=(3, NUM_KEYPOINTS, 3))
    pred = true + np.array([0.03, 0.0, 0.04])  # 50 mm off everywhere, angles unchanged
    true[0, KP["left_small_toe"]] = np.nan  # an imported label without small toes
    true[2] = np.nan  # no pose label at all
    assert mpjpe_mm(pred, true) == pytest.approx(50.0)
    assert mpjpe_mm(pred, true, [True, False, True]) == pytest.approx(50.0)  # frame 2 empty
    assert mpjae_deg(pred, true) == pytest.approx(0.0, abs=1e-9)
    assert np.isnan(mpjpe_mm(pred[2:], true[2:]))
