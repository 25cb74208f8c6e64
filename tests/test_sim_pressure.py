"""Plantar pressure: loads follow the COM, the COP rolls the right way, counts are exact.

The contact model's own physics (force, COP, load shares, arch types) is in
tests/test_sim_contact.py; the insole as a sensor in tests/test_sim_insole.py.
"""

from __future__ import annotations

import numpy as np
import pytest
from scotti.models.contract import FRAME_COLS, FRAME_ROWS, MAX_COUNT
from scotti.sim.foot_mask import insole_length_m, insole_mask
from scotti.sim.insole import IDEAL, REALISTIC, InsoleArray, counts_from_kpa, to_uint16
from scotti.sim.loads import FootLoads, G, foot_loads, vertical_acceleration
from scotti.sim.plantar import REGION_NAMES
from scotti.sim.pressure import PressureRenderer
from scotti.sim.writer import SimInput, render_counts

from tests.support.sim_synthetic import (
    FOOT_LENGTH_M,
    MASS_KG,
    SyntheticMotion,
    jump,
    standing,
    synthetic_input,
    walking,
)


def _loads(m: SyntheticMotion) -> FootLoads:
    return foot_loads(m.keypoints, m.com, m.rate_hz, m.subject.mass_kg)


def _sim(m: SyntheticMotion) -> SimInput:
    return synthetic_input(m)


def _cop_row(forces: np.ndarray) -> np.ndarray:
    """Row of the centre of pressure per frame and foot (0 toes .. 31 heel)."""
    rows = np.arange(FRAME_ROWS)
    per_row = forces.sum(axis=-1)
    return np.asarray((per_row * rows).sum(-1) / np.maximum(per_row.sum(-1), 1e-9))


def test_mask_is_a_foot_shaped_outline() -> None:
    mask = insole_mask()
    assert mask.shape == (FRAME_ROWS, FRAME_COLS)
    assert 0.6 < mask.mean() < 0.85
    # widest across the forefoot (upper third), narrower at the heel end
    widths = mask.sum(axis=1)
    assert widths[: FRAME_ROWS // 3].max() > widths[-4:].max() + 4
    # the big toe is medial: the first row's taxels sit in the medial half
    first = np.flatnonzero(mask[0])
    assert first.mean() < FRAME_COLS / 2


def test_plantar_regions_lie_heel_to_toe_inside_the_mask() -> None:
    region = PressureRenderer(0.26).region[0]
    assert not (region[~insole_mask()] >= 0).any()
    rows = np.arange(FRAME_ROWS)[:, None] * np.ones((1, FRAME_COLS))
    mean_row = [rows[region == r].mean() for r in range(len(REGION_NAMES))]
    assert mean_row == sorted(mean_row, reverse=True)  # heel (row 31) first, toes last
    assert insole_length_m(0.26) >= 0.26
    assert insole_length_m(0.26) - 0.26 < 0.016


def test_standing_carries_body_weight_split_evenly() -> None:
    loads = _loads(standing())
    weight = MASS_KG * G
    np.testing.assert_allclose(loads.load_n.sum(axis=1), weight, rtol=0.1)
    np.testing.assert_allclose(loads.load_n[:, 0], loads.load_n[:, 1], rtol=1e-9)
    forces = PressureRenderer(FOOT_LENGTH_M).forces(loads)
    np.testing.assert_allclose(forces.sum(axis=(2, 3)), loads.load_n, rtol=1e-4)


def test_standing_peaks_at_heel_and_forefoot_not_midfoot() -> None:
    kpa = PressureRenderer(FOOT_LENGTH_M).kpa(_loads(standing(2)))[0, 0]
    heel, midfoot, forefoot = kpa[24:].max(), kpa[14:20].max(), kpa[7:13].max()
    assert heel > 2 * midfoot
    assert forefoot > 2 * midfoot
    assert 30 < heel < 300  # kPa, quiet stance


def test_flight_carries_nothing_and_the_landing_more_than_weight() -> None:
    m = jump(48, flight_frames=(20, 27))
    loads = _loads(m)
    assert np.all(loads.load_n[21:27] == 0.0)
    counts = render_counts(_sim(m))
    assert not counts[21:27].any()
    assert loads.load_n[28].sum() > MASS_KG * G  # decelerating the fall


def test_vertical_acceleration_of_a_parabola() -> None:
    t = np.arange(40) / 16.0
    z = 1.0 - 0.5 * 9.81 * t * t
    np.testing.assert_allclose(vertical_acceleration(z, 16.0)[2:-2], -9.81, rtol=1e-9)


def test_cop_moves_heel_to_toe_during_a_walking_stance() -> None:
    m = walking(40)
    loads = _loads(m)
    forces = PressureRenderer(FOOT_LENGTH_M).forces(loads)
    cop = _cop_row(forces)[:, 0]  # left foot: heel strike at frame 18 (cycle 2)
    stance = np.flatnonzero(loads.load_n[:, 0] > 50)
    one = stance[(stance >= 17) & (stance <= 28)]
    assert cop[one[0]] > 24  # heel first
    assert cop[one[-1]] < 11  # the forefoot last (metatarsal heads and on)
    assert np.all(np.diff(cop[one]) <= 0.5)  # rolling forward all along


def test_cop_starts_on_the_forefoot_when_the_heel_is_up() -> None:
    m = standing(4)
    kp = m.keypoints.copy()
    kp[:, [15, 18], 2] = 0.06  # both heels up, toes on the floor: tiptoe
    loads = foot_loads(kp, m.com, 16.0, MASS_KG)
    cop = _cop_row(PressureRenderer(FOOT_LENGTH_M).forces(loads))
    assert np.all(cop < 10)


def test_leaning_sideways_rolls_onto_an_edge() -> None:
    m = standing(2)
    com = m.com.copy()
    com[:, 1] = 0.1  # over the left foot
    loads = foot_loads(m.keypoints, com, 16.0, MASS_KG)
    assert loads.load_n[0, 0] > 3 * loads.load_n[0, 1]
    forces = PressureRenderer(FOOT_LENGTH_M).forces(loads)
    cols = np.arange(FRAME_COLS)
    cop_col = (forces.sum(axis=2) * cols).sum(-1) / forces.sum(axis=(2, 3))
    # right foot: the COM far medial -> its medial edge (low columns)
    assert cop_col[0, 1] < cop_col[0, 0] - 2


def test_ideal_transfer_curve_is_monotone_half_scale_at_p_half_and_clipped() -> None:
    kpa = np.linspace(0, 5000, 501)
    counts = counts_from_kpa(kpa, IDEAL)
    assert counts[0] == 0.0
    assert np.all(np.diff(counts) >= 0)
    assert counts.max() <= MAX_COUNT
    half = counts_from_kpa(np.array([IDEAL.p_half_kpa + IDEAL.threshold_kpa]), IDEAL)[0]
    assert abs(half - MAX_COUNT / 2) < 1
    assert to_uint16(np.array([-5.0, 4095.4, 9999.0])).tolist() == [0, 4095, 4095]


def test_rendering_is_deterministic_and_noise_free() -> None:
    m = walking(32)
    a = render_counts(_sim(m))
    b = render_counts(_sim(m))
    assert a.dtype == np.uint16
    assert a.shape == (32, 2, FRAME_ROWS, FRAME_COLS)
    np.testing.assert_array_equal(a, b)
    assert not a[:, :, ~insole_mask()].any()
    assert a.max() > 500  # walking loads show up


@pytest.mark.parametrize("chunk", [5, 1024])
def test_chunked_rendering_equals_whole(chunk: int) -> None:
    from scotti.sim.effects.registry import EffectPlan, parse_effects
    from scotti.sim.writer import CountsStream

    m = walking(24)
    sim = _sim(m)
    renderer = PressureRenderer(FOOT_LENGTH_M)
    effects = parse_effects([{"name": "hysteresis"}, {"name": "creep"}, {"name": "noise"}])

    def stream(c: int) -> np.ndarray:
        plan = EffectPlan.build(effects, seed=3, rate_hz=16.0, mask=renderer.mask)
        insole = InsoleArray(REALISTIC, seed=3)
        return CountsStream(sim.loads(), renderer, plan, insole, chunk_frames=c).all()

    np.testing.assert_array_equal(stream(chunk), stream(7))
