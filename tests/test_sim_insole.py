"""The insole as a sensor: activation threshold, transfer curve, saturation, gain spread."""

from __future__ import annotations

import numpy as np
import pytest
from scotti.models.contract import FRAME_COLS, FRAME_ROWS, MAX_COUNT
from scotti.sim.foot_mask import insole_mask
from scotti.sim.insole import (
    IDEAL,
    REALISTIC,
    Insole,
    InsoleArray,
    InsoleSpec,
    counts_from_kpa,
    draw_insole,
)
from scotti.sim.scene import Scene, SceneError
from scotti.sim.writer import render_counts

from tests.support.sim_synthetic import jump, synthetic_input, walking

SCENE = """
[subject]
height_m = 1.7
mass_kg = 65.0
[[script]]
action = "squat"
reps = 1
"""


def test_below_the_activation_pressure_a_taxel_reads_zero() -> None:
    insole = REALISTIC
    below = np.linspace(0.0, insole.threshold_kpa, 50)
    assert not counts_from_kpa(below, insole).any()
    above = counts_from_kpa(np.array([insole.threshold_kpa + 2.0, 100.0]), insole)
    assert (above > 0).all()


def test_a_foot_without_load_reads_all_zeros() -> None:
    m = jump(40, flight_frames=(16, 26))
    counts = render_counts(synthetic_input(m), seed=3)
    assert not counts[18:25].any()  # in the air: nothing, whatever the gains
    assert counts[:10].any()


def test_realistic_contact_is_sparser_than_ideal() -> None:
    sim = synthetic_input(walking(48))
    real = render_counts(sim, seed=1, insole=REALISTIC)
    ideal = render_counts(sim, seed=1, insole=IDEAL)
    # each pressed taxel of the realistic insole is pressed on the ideal one too
    assert not ((real > 0) & (ideal == 0)).any()
    assert (real > 0).sum() < 0.9 * (ideal > 0).sum()


def test_transfer_curve_is_a_power_law_through_a_divider() -> None:
    insole = Insole(threshold_kpa=10.0, p_half_kpa=200.0, exponent=0.7, gain_sigma=0.0)
    q = np.array([0.25, 0.5, 1.0])  # kPa above threshold, far below p_half
    counts = counts_from_kpa(q + insole.threshold_kpa, insole).astype(np.float64)
    slope = np.diff(np.log(counts)) / np.diff(np.log(q))
    np.testing.assert_allclose(slope, insole.exponent, atol=0.03)  # light: conductance ~ q^n
    half = counts_from_kpa(np.array([insole.p_half_kpa + insole.threshold_kpa]), insole)
    assert abs(half[0] - MAX_COUNT / 2) < 2
    curve = counts_from_kpa(np.linspace(0, 3000, 300), insole)
    assert (np.diff(curve) >= 0).all()
    assert (np.diff(curve, 2)[curve[:-2] > 0] <= 1e-3).all()  # compressing towards full scale


def test_saturation_rails_the_counts() -> None:
    insole = Insole(saturation_counts=3000.0)
    counts = counts_from_kpa(np.array([500.0, 5000.0, 1e6]), insole)
    assert counts.max() == 3000.0
    assert counts[-1] == 3000.0
    assert counts_from_kpa(np.array([1e6]), IDEAL)[0] <= MAX_COUNT


def test_gain_spread_is_lognormal_with_mean_one_and_drawn_per_insole() -> None:
    sigma = 0.2
    a = InsoleArray(Insole(gain_sigma=sigma), seed=1)
    assert a.gain is not None
    assert a.gain.shape == (2, FRAME_ROWS, FRAME_COLS)
    log_gain = np.log(a.gain.astype(np.float64))
    assert abs(a.gain.mean() - 1.0) < 0.02
    assert abs(log_gain.std() - sigma) < 0.015
    assert not np.array_equal(a.gain[0], a.gain[1])  # each foot's insole its own
    b = InsoleArray(Insole(gain_sigma=sigma), seed=1)
    c = InsoleArray(Insole(gain_sigma=sigma), seed=2)
    assert b.gain is not None
    assert c.gain is not None
    np.testing.assert_array_equal(a.gain, b.gain)
    assert not np.array_equal(a.gain, c.gain)
    ideal = InsoleArray(IDEAL, seed=1)
    kpa = np.full((1, 2, FRAME_ROWS, FRAME_COLS), 50.0, np.float32)
    np.testing.assert_array_equal(ideal.sensed_kpa(kpa), kpa)


def test_drawn_insoles_stay_in_their_ranges() -> None:
    rng = np.random.default_rng(0)
    for _ in range(50):
        insole = draw_insole(rng)
        assert 8 <= insole.threshold_kpa <= 35
        assert 0.6 <= insole.exponent <= 1.0
        assert 3500 <= insole.saturation_counts <= MAX_COUNT
        InsoleSpec.model_validate(insole.as_dict())  # a drawn insole is a valid table


def test_scene_names_its_insole_and_overrides_parameters() -> None:
    default = Scene.from_toml_text(SCENE)
    assert default.insole.resolved() == REALISTIC
    ideal = Scene.from_toml_text(SCENE + '[insole]\nmodel = "ideal"\nsaturation_counts = 3900\n')
    assert ideal.insole.resolved() == Insole(**{**IDEAL.as_dict(), "saturation_counts": 3900.0})  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("table", "message"),
    [
        ('model = "perfect"', "scene.toml line 9: insole.model: Input should be 'realistic' or"),
        ("threshold_kpa = -1", "scene.toml line 9: insole.threshold_kpa: Input should be greater"),
        ("gain = 0.1", "scene.toml line 9: insole.gain: Extra inputs are not permitted"),
    ],
)
def test_bad_insole_tables_are_one_line_errors(table: str, message: str) -> None:
    with pytest.raises(SceneError) as info:
        Scene.from_toml_text(SCENE + "[insole]\n" + table + "\n")
    assert str(info.value).startswith(message)
    assert "\n" not in str(info.value)


def test_counts_stay_on_the_insole_outline() -> None:
    counts = render_counts(synthetic_input(walking(32)), seed=4)
    assert not counts[:, :, ~insole_mask()].any()
    assert counts.max() <= REALISTIC.saturation_counts


def test_wide_insoles_reach_the_insoles_users_bring() -> None:
    rng = np.random.default_rng(0)
    drawn = [draw_insole(rng, "wide") for _ in range(400)]
    thresholds = np.array([i.threshold_kpa for i in drawn])
    halves = np.array([i.p_half_kpa for i in drawn])
    spreads = np.array([i.gain_sigma for i in drawn])
    # A soft insole (threshold 45 kPa, half scale 450) and a gain spread of 0.45
    # read squats as standing with the typical draws; the wide ones include them.
    assert thresholds.max() > 45
    assert thresholds.min() < 5
    assert halves.max() > 450
    assert halves.min() < 120
    assert spreads.max() > 0.45
    # The typical draw is what it was: old corpora remake byte for byte.
    assert draw_insole(np.random.default_rng(0)) == draw_insole(np.random.default_rng(0), "typical")
    assert draw_insole(np.random.default_rng(0)).threshold_kpa <= 35
    for insole in drawn:
        InsoleSpec.model_validate(insole.as_dict())
