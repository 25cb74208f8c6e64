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
