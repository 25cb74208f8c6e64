"""The input checks (models/input_checks.py) and the unfamiliar score (models/ood.py)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scotti.models import input_checks as ic
from scotti.models.contract import FRAME_COLS, FRAME_ROWS, MAX_COUNT, WINDOW
from scotti.models.errors import ModelContractError
from scotti.models.insole import counts_from_kpa, insole_mask
from scotti.models.ood import (
    MIN_CLASS_WINDOWS,
    OOD_FLAGS,
    UNFAMILIAR,
    OodStats,
    fit,
    flag_shares,
    format_flag_shares,
    shrunk_covariance,
    withheld,
)
from scotti.models.window_checks import FrameChecks

MASK = insole_mask()


def foot_map(kpa_peak: float, seed: int = 0) -> np.ndarray:
    """A smooth plantar map (32, 22) of counts: heel and forefoot blobs inside the outline."""
    r, c = np.mgrid[0:FRAME_ROWS, 0:FRAME_COLS]
    rng = np.random.default_rng(seed)
    heel = np.exp(-((r - 26) ** 2 / 18 + (c - 11) ** 2 / 10))
    fore = np.exp(-((r - 8) ** 2 / 20 + (c - 9 - rng.uniform(-1, 1)) ** 2 / 16))
    return counts_from_kpa(kpa_peak * np.maximum(heel, fore)) * MASK


def frame(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    return np.concatenate([left, right], axis=1)


def test_kpa_from_counts_turns_the_transfer_curve_round() -> None:
    kpa = np.array([0.0, 10.0, 25.0, 80.0, 300.0, 1500.0])
    back = ic.kpa_from_counts(counts_from_kpa(kpa))
    assert back[0] == 0.0
    assert back[1] == 0.0  # below the activation threshold a taxel reads 0: nothing to invert
    np.testing.assert_allclose(back[2:], kpa[2:], rtol=1e-3)
    # At and beyond the rail: the rail's pressure, finite.
    assert np.isfinite(ic.kpa_from_counts(np.array([MAX_COUNT, 70000.0]))).all()


def test_a_person_standing_is_loaded_and_plausible() -> None:
    standing = frame(foot_map(250.0), foot_map(250.0, seed=1))
    check = ic.check_frame(standing)
    assert 100.0 < sum(check.force_n) < ic.FORCE_MAX_N
    assert check.loaded
    assert check.implausible == []
    window = np.stack([standing] * WINDOW)
    assert ic.check_window(window).flags == ()


def test_each_rule_names_what_it_saw() -> None:
    empty = np.zeros((FRAME_ROWS, 2 * FRAME_COLS))
    assert not ic.check_frame(empty).loaded
    assert ic.check_frame(empty).implausible == []  # empty is unloaded, not out of range
    hot = empty.copy()
    hot[12, FRAME_COLS + 10] = MAX_COUNT
    assert ic.check_frame(hot).implausible == ["one taxel holds the load"]
    outside = frame(foot_map(250.0), foot_map(250.0))
    outside[:3, :3] = MAX_COUNT  # toe corner, medial: outside the outline, no taxel there
    assert "load outside the insole outline" in ic.check_frame(outside).implausible
    railed = frame(np.where(MASK, ic.RAIL_COUNTS + 10, 0), foot_map(250.0))
    assert "taxels at the rail" in ic.check_frame(railed).implausible
    assert "more force than a landing" in ic.check_frame(railed).implausible


def test_unloaded_needs_a_second_of_empty_insoles_so_a_jump_flight_is_not_one() -> None:
    standing = frame(foot_map(250.0), foot_map(250.0))
    empty = np.zeros_like(standing)
    flight = np.stack([standing] * (WINDOW - 8) + [empty] * 8)  # half a second in the air
    assert ic.check_window(flight).flags == ()
    gone = np.stack([standing] * (WINDOW - ic.UNLOADED_FRAMES) + [empty] * ic.UNLOADED_FRAMES)
    verdict = ic.check_window(gone)
    assert verdict.flags == (ic.UNLOADED,)
    assert verdict.reasons[0].startswith("unloaded: ")


def test_one_corrupt_frame_is_not_out_of_range_but_a_quarter_second_is() -> None:
    standing = frame(foot_map(250.0), foot_map(250.0))
    noise = np.random.default_rng(0).uniform(0, MAX_COUNT, standing.shape)
    window = np.stack([standing] * WINDOW)
    window[10] = noise
    assert ic.check_window(window).flags == ()
    window[10 : 10 + ic.OUT_OF_RANGE_FRAMES] = noise
    assert ic.check_window(window).flags == (ic.OUT_OF_RANGE,)


def test_one_insole_empty_for_a_whole_window_is_out_of_range_and_a_step_is_not() -> None:
    left, right = foot_map(400.0), foot_map(400.0)
    one_foot = np.stack([frame(left, np.zeros_like(right))] * WINDOW)
    verdict = ic.check_window(one_foot)
    assert verdict.flags == (ic.OUT_OF_RANGE,)
    assert "right insole empty for the whole window" in verdict.reasons[0]
    walking = one_foot.copy()
    walking[:20, :, FRAME_COLS:] = right  # the right foot was down half the window ago
    assert ic.check_window(walking).flags == ()


def test_streaming_checks_forget_on_reset() -> None:
    checks = FrameChecks(WINDOW)
    empty = np.zeros((FRAME_ROWS, 2 * FRAME_COLS))
    for _ in range(ic.UNLOADED_FRAMES - 1):
        assert checks.push(empty).flags == ()
    assert checks.push(empty).flags == (ic.UNLOADED,)
    checks.reset()
    assert checks.push(empty).flags == ()


def test_withheld_takes_the_first_flag_and_shares_count_each() -> None:
    assert OOD_FLAGS == (ic.UNLOADED, ic.OUT_OF_RANGE, UNFAMILIAR)
    assert withheld(("left_filled",)) is None
    assert withheld((UNFAMILIAR, ic.UNLOADED)) == ic.UNLOADED
    shares = flag_shares([(), (ic.UNLOADED, UNFAMILIAR), ("rows_missing",), (UNFAMILIAR,)])
    assert shares == {
        "unloaded": 0.25,
        "out_of_range": 0.0,
        "unfamiliar": 0.5,
        "any": 0.5,
        "predictions": 4,
    }
    line = format_flag_shares(shares, {"calibrated": False})
    assert "unloaded 25.00 %" in line
    assert "not calibrated" in line


def gaussian(n: int, dim: int, seed: int, scale: np.ndarray) -> np.ndarray:
    return np.random.default_rng(seed).normal(size=(n, dim)) * scale


def test_shrinkage_matches_the_closed_form_and_whitening_whitens() -> None:
    dim = 12
    x = gaussian(60, dim, 0, np.linspace(0.2, 3.0, dim))
    cov, shrink = shrunk_covariance(x)
    # Ledoit-Wolf written out term by term: the sampling noise of S over its distance
    # from the scaled identity.
    z = x - x.mean(axis=0)
    s = z.T @ z / len(x)
    mu = np.trace(s) / dim
    b2 = sum(((np.outer(r, r) - s) ** 2).sum() for r in z) / len(x) ** 2
    d2 = ((s - mu * np.eye(dim)) ** 2).sum()
    assert shrink == pytest.approx(min(1.0, b2 / d2), rel=1e-9)
    np.testing.assert_allclose(cov, (1 - shrink) * s + shrink * mu * np.eye(dim), rtol=1e-9)
    stats = fit(x, gaussian(30, dim, 1, np.ones(dim)))
    w = stats.whitening.astype(np.float64)
    np.testing.assert_allclose(w @ cov @ w.T, np.eye(dim), atol=1e-4)


def test_threshold_flags_about_one_percent_of_held_out_and_most_of_a_shift() -> None:
    dim = 16
    scale = np.linspace(0.2, 3.0, dim)
    stats = fit(gaussian(4000, dim, 0, scale), gaussian(4000, dim, 1, scale), percentile=99.0)
    fresh = stats.score(gaussian(4000, dim, 2, scale))
    assert 0.003 < float((fresh > stats.threshold).mean()) < 0.03
    # The same spread, moved along the narrowest axis by 3 of the widest axis' sigmas.
    shifted = gaussian(1000, dim, 3, scale)
    shifted[:, 0] += 9.0
    assert float((stats.score(shifted) > stats.threshold).mean()) > 0.99
    assert stats.summary["threshold"] == stats.threshold
    assert stats.summary["held_out_windows"] == 4000


def test_statistics_round_trip_through_metadata_and_bad_ones_are_one_line() -> None:
    dim = 8
    stats = fit(gaussian(200, dim, 0, np.ones(dim)), gaussian(100, dim, 1, np.ones(dim)))
    back = OodStats.from_json(stats.to_json(), dim)
    np.testing.assert_array_equal(back.mean, stats.mean)
    np.testing.assert_array_equal(back.whitening, stats.whitening)
    assert back.threshold == stats.threshold
    x = gaussian(5, dim, 2, np.ones(dim))
    np.testing.assert_allclose(back.score(x), stats.score(x))
    with pytest.raises(ModelContractError, match="E=8, the model has E=16"):
        OodStats.from_json(stats.to_json(), 16)
    broken = json.loads(stats.to_json())
    broken["whitening"] = broken["mean"]
    with pytest.raises(ModelContractError, match="whitening is not"):
        OodStats.from_json(json.dumps(broken), dim)
    broken = json.loads(stats.to_json())
    broken["threshold"] = -1
    with pytest.raises(ModelContractError, match="positive number"):
        OodStats.from_json(json.dumps(broken), dim)
    with pytest.raises(ModelContractError, match="not a JSON object"):
        OodStats.from_json("[1, 2]", dim)


def two_actions(n: int, dim: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A common action (label 0, 90 %) round the origin and a rarer one (label 1) six
    sigmas away on two axes, each with unit spread: a squat beside the rest."""
    rng = np.random.default_rng(seed)
    labels = (rng.random(n) < 0.1).astype(np.int64)
    x = rng.normal(size=(n, dim))
    x[labels == 1, :2] += 6.0
    return x, labels


def flagged(stats: OodStats, x: np.ndarray, actions: np.ndarray | None = None) -> float:
    return float((stats.score(x, actions) > stats.threshold).mean())


def test_per_action_means_call_a_rare_action_as_familiar_as_a_common_one() -> None:
    dim = 16
    train, labels = two_actions(4000, dim, 0)
    held, held_labels = two_actions(4000, dim, 1)
    fresh, fresh_labels = two_actions(20000, dim, 2)
    rare, common = fresh_labels == 1, fresh_labels == 0
    one_mean = fit(train, held)
    # The model called each held-out window right.
    per_action = fit(train, held, 99.0, labels, held_labels, ("common", "rare"))
    assert per_action.threshold == 1.0
    # One Gaussian over both puts the rare action's ordinary windows in its tail ...
    assert flagged(one_mean, fresh[rare]) > 4 * flagged(one_mean, fresh[common])
    # ... each action's own mean and threshold flag both alike, about 1 %.
    assert 0.003 < flagged(per_action, fresh[rare], fresh_labels[rare]) < 0.025
    assert 0.003 < flagged(per_action, fresh[common], fresh_labels[common]) < 0.025
    summary = per_action.summary["actions"]
    assert summary["rare"]["train_windows"] == int((labels == 1).sum())
    assert summary["rare"]["held_out_windows"] == int((held_labels == 1).sum())
    assert "predicted action" in per_action.summary["method"]
    # Still a detector: the rare action moved off along another axis is unfamiliar.
    moved = fresh[rare].copy()
    moved[:, 5] += 6.0
    assert flagged(per_action, moved, fresh_labels[rare]) > 0.95


def test_a_window_of_one_action_called_another_is_unfamiliar() -> None:
    """What the nearest mean misses: real walking the model calls a confident step_up
    lies near the walking mean, so it is familiar to some action, not to the one named."""
    dim = 16
    train, labels = two_actions(4000, dim, 0)
    held, held_labels = two_actions(4000, dim, 1)
    stats = fit(train, held, 99.0, labels, held_labels)
    fresh, fresh_labels = two_actions(2000, dim, 3)
    common = fresh[fresh_labels == 0]
    called_rare = np.ones(len(common), dtype=np.int64)
    assert flagged(stats, common[:100] * 0.0) == 0.0  # the common mean itself, by min
    assert flagged(stats, common, called_rare) > 0.99
    # Without a prediction (or one with no mean) the smallest ratio decides.
    nearest = stats.score(common)
    np.testing.assert_allclose(stats.score(common, np.full(len(common), 7)), nearest)
    np.testing.assert_allclose(stats.score(common, np.full(len(common), -1)), nearest)
    assert flagged(stats, common) < 0.05


def test_the_score_is_the_distance_to_the_predicted_mean_over_its_threshold() -> None:
    dim = 6
    train, labels = two_actions(600, dim, 0)
    labels[:50] = -1  # windows without an action fit neither mean nor covariance
    held, held_labels = two_actions(400, dim, 1)
    stats = fit(train, held, 95.0, labels, held_labels)
    am = stats.action_means
    assert am is not None
    assert am.actions == (0, 1)
    x = np.random.default_rng(3).normal(size=(7, dim)) * 3
    called = np.array([0, 1, 1, 0, 1, 0, 0])
    w = stats.whitening.astype(np.float64)
    brute = [
        np.linalg.norm(w @ (row - am.means[a])) / am.thresholds[a]
        for row, a in zip(x, called, strict=True)
    ]
    np.testing.assert_allclose(stats.score(x, called), brute, rtol=1e-5)
    np.testing.assert_allclose(stats.score(am.means, np.array([0, 1])), 0.0, atol=1e-3)
    kept = labels == 1
    np.testing.assert_allclose(am.means[1], train[kept].mean(axis=0), rtol=1e-5)
    # Each threshold: the 95th percentile of the held-out windows called that action.
    d1 = [np.linalg.norm(w @ (row - am.means[1])) for row in held[held_labels == 1]]
    assert am.thresholds[1] == pytest.approx(np.percentile(d1, 95.0), rel=1e-4)


def test_too_few_windows_fall_back_to_one_mean_or_the_nearest_threshold() -> None:
    dim = 4
    train, labels = two_actions(400, dim, 0)
    few = np.full(400, -1)
    few[: MIN_CLASS_WINDOWS - 1] = 0  # one action, one window short
    stats = fit(train, train[:50], train_labels=few)
    assert stats.action_means is None
    assert "actions" not in stats.summary
    np.testing.assert_allclose(stats.score(train), fit(train, train[:50]).score(train))
    # Enough training windows, but the held-out windows called the rare action are too
    # few for a threshold of its own: it takes the nearest mean's.
    held, _ = two_actions(200, dim, 1)
    called = np.zeros(200, dtype=np.int64)
    called[: MIN_CLASS_WINDOWS - 1] = 1
    stats = fit(train, held, 99.0, labels, called)
    assert stats.summary["actions"]["1"]["held_out_windows"] == MIN_CLASS_WINDOWS - 1
    am = stats.action_means
    assert am is not None
    assert am.thresholds[0] != am.thresholds[1]
    nearest_stats = fit(train, held, 99.0, labels, None)
    nearest = nearest_stats.action_means
    assert nearest is not None
    assert am.thresholds[1] == pytest.approx(nearest.thresholds[1])
    # Without predictions: Lee et al.'s rule, the nearest mean and one threshold, whatever
    # action a window is called.
    assert not nearest.by_prediction
    assert nearest.thresholds[0] == pytest.approx(nearest.thresholds[1])
    assert "nearest action" in nearest_stats.summary["method"]
    called_rare = np.ones(len(train), dtype=np.int64)
    np.testing.assert_allclose(nearest_stats.score(train, called_rare), nearest_stats.score(train))
    back = OodStats.from_json(nearest_stats.to_json(), dim)
    assert back.action_means is not None
    assert not back.action_means.by_prediction


def test_action_means_round_trip_through_metadata_and_bad_ones_are_one_line() -> None:
    dim = 8
    train, labels = two_actions(400, dim, 0)
    stats = fit(train, train[:100], 99.0, labels, labels[:100])
    back = OodStats.from_json(stats.to_json(), dim)
    assert back.action_means is not None
    assert stats.action_means is not None
    assert back.action_means.actions == stats.action_means.actions
    np.testing.assert_array_equal(back.action_means.means, stats.action_means.means)
    np.testing.assert_array_equal(back.action_means.thresholds, stats.action_means.thresholds)
    np.testing.assert_allclose(
        back.score(train[:9], labels[:9]), stats.score(train[:9], labels[:9])
    )
    good = json.loads(stats.to_json())
    for key, value, message in (
        ("actions", [0, 1, 2], "action_means is not"),
        ("actions", [0, 0], "distinct action indices"),
        ("actions", "two", "distinct action indices"),
        ("action_thresholds", good["mean"], "action_thresholds is not"),
        ("by", "farthest", "'prediction' or 'nearest'"),
    ):
        broken = {**good, key: value}
        with pytest.raises(ModelContractError, match=message):
            OodStats.from_json(json.dumps(broken), dim)
    negative = OodStats(
        stats.mean,
        stats.whitening,
        1.0,
        action_means=type(stats.action_means)(
            (0, 1), stats.action_means.means, -np.ones(2, np.float32)
        ),
    )
    with pytest.raises(ModelContractError, match="positive numbers"):
        OodStats.from_json(negative.to_json(), dim)
    # Statistics written before there were action means still load: one global mean.
    legacy = json.loads(fit(train, train[:100]).to_json())
    assert "action_means" not in legacy
    assert OodStats.from_json(json.dumps(legacy), dim).action_means is None
