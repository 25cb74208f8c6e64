"""experiments/real_vs_sim_gait.py: the gait measures on a constructed walk of known timing.

Each foot presses its heel for the first half of a stance and its forefoot for
the second, at one pressure, the right foot half a stride after the left; the
cadence, stance, swing, double support, heel share, centre of pressure, zero
cells and count scale then follow from the construction.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from scotti.models.contract import FRAME_COLS, FRAME_RATE_HZ, FRAME_ROWS
from scotti.models.insole import counts_from_kpa, insole_mask

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "experiments"))

import real_vs_sim_gait as gait

KPA = 100.0
HEEL_ROWS = slice(22, 32)
FORE_ROWS = slice(3, 13)


def walk(stride: int, stance: int, strides: int, noise: bool = False) -> np.ndarray:
    """(N, 32, 44) counts: ``strides`` strides of ``stride`` frames, ``stance`` on the ground."""
    mask = insole_mask()
    level = np.rint(counts_from_kpa(np.array(KPA))).astype(np.uint16)
    n = stride * strides
    frames = np.zeros((n, FRAME_ROWS, 2 * FRAME_COLS), np.uint16)
    rng = np.random.default_rng(3)
    for foot, offset in ((0, 0), (1, stride // 2)):
        cols = slice(foot * FRAME_COLS, (foot + 1) * FRAME_COLS)
        for i in range(n):
            phase = (i - offset) % stride
            sole = np.zeros((FRAME_ROWS, FRAME_COLS), np.uint16)
            if phase < stance:
                rows = HEEL_ROWS if phase < stance // 2 else FORE_ROWS
                sole[rows] = level
            elif noise:  # a foot in the air reading the electronics' noise, under the floor
                sole = rng.integers(0, gait.NOISE_COUNTS, sole.shape).astype(np.uint16)
            frames[i, :, cols] = np.where(mask, sole, 0)
    return frames


@pytest.mark.parametrize(("stride", "stance"), [(20, 12), (24, 16)])
def test_timing_follows_the_constructed_stride_and_stance(stride: int, stance: int) -> None:
    rate = float(FRAME_RATE_HZ)
    g = gait.measure(walk(stride, stance, 12), [(0, stride * 12)], rate)
    assert g.cadence == pytest.approx(2 * 60 * rate / stride)
    assert g.stance_s == pytest.approx(stance / rate)
    assert g.swing_s == pytest.approx((stride - stance) / rate)
    # Each foot's stance overlaps the other's for stance - stride/2 frames at both ends.
    assert g.double_support == pytest.approx(2 * (stance - stride / 2) / stride)
    assert g.stance_lr == pytest.approx(1.0)
    assert g.load_lr == pytest.approx(1.0, abs=0.02)


def test_where_and_how_much_the_feet_press() -> None:
    g = gait.measure(walk(20, 12, 10), [(0, 200)], float(FRAME_RATE_HZ))
    mask = insole_mask()
    heel, fore = int(mask[HEEL_ROWS].sum()), int(mask[FORE_ROWS].sum())
    # Half the stance on each region at one pressure: the load is in proportion to the area.
    assert g.heel_share == pytest.approx(heel / (heel + fore), abs=1e-6)
    rows = np.arange(FRAME_ROWS)
    heel_centre = 1.0 - (rows[HEEL_ROWS] + 0.5).mean() / FRAME_ROWS
    assert g.cop_start == pytest.approx(heel_centre, abs=0.02)
    assert g.cop_end > 0.7  # on the forefoot at push-off
    assert g.zero_share == pytest.approx(1.0 - (heel + fore) / 2 / mask.sum(), abs=1e-6)
    level = np.rint(counts_from_kpa(np.array(KPA)))
    assert g.counts_median == level
    assert g.peak_bw > 0.9  # one foot alone carries what both carry


def test_noise_under_the_floor_does_not_hold_a_foot_on_the_ground() -> None:
    clean = gait.measure(walk(20, 12, 10), [(0, 200)], float(FRAME_RATE_HZ))
    noisy = gait.measure(walk(20, 12, 10, noise=True), [(0, 200)], float(FRAME_RATE_HZ))
    assert noisy.stance_s == clean.stance_s
    assert noisy.double_support == clean.double_support


def test_runs_split_at_label_gaps_and_restarts() -> None:
    keep = np.array([1, 1, 1, 0, 1, 1, 1, 1, 0], bool)
    segment = np.array([0, 0, 0, 0, 0, 0, 1, 1, 1])
    assert gait.runs_of(keep, segment) == [(0, 3), (4, 6), (6, 8)]
    on = np.array([1, 1, 0, 1, 1, 0, 0, 1, 0, 1], bool)
    assert gait.contact_runs(on) == [(3, 5), (7, 8)]  # the ones cut by the ends are dropped


def test_every_real_walk_of_real_data_is_measured() -> None:
    # The other insoles' walks (pedar, Moticon) beside gaitpdb's, under the names real_data.py
    # imports them to: a file renamed there would be missing here, not silently skipped.
    sys.path.insert(0, str(Path(gait.__file__).parent))
    import real_data

    walks = {r.name for r in real_data.RECORDINGS if r.activity == "walking" and not r.one_foot}
    measured = {f"{name}_01" for name in gait.REAL} | {stem for _, _, stem in gait.OTHER_REAL}
    assert walks == measured
