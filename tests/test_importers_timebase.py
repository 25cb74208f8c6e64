"""Time: segments at gaps, sequence jumps, the box average and keypoint interpolation by hand."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scotti.importers.config import config_from_dict
from scotti.importers.feet import FEET, resample_feet
from scotti.importers.sources import load_pressure
from scotti.importers.timebase import (
    PERIOD_S,
    RESTART_GAP_S,
    box_average,
    interpolate_points,
    plan_timeline,
)
from scotti.models.contract import FRAME_COLS, FRAME_ROWS, MAX_COUNT, WINDOW_RESTART_GAP_FRAMES

from tests.support.foreign import pressure_frames, write_pressure_csv
from tests.support.vendor_files import write_moticon


def test_frames_every_sixteenth_on_the_source_clock() -> None:
    t = 1000.0 + np.arange(0, 2.0, 0.01)  # 100 Hz, 1.99 s, a clock far from zero
    tl = plan_timeline(t)
    assert len(tl) == 32  # 0 .. 31/16 = 1.9375 s <= 1.99 s
    np.testing.assert_allclose(tl.times, 1000.0 + np.arange(32) / 16)
    np.testing.assert_array_equal(tl.seq, np.arange(32))


def test_a_long_gap_splits_and_jumps_the_sequence() -> None:
    first = np.arange(0, 1.0, 0.05)  # up to 0.95 s
    second = 3.0 + np.arange(0, 1.0, 0.05)  # 2.05 s later: more than the restart gap
    short = 5.0 + np.arange(0, 0.5, 0.05)  # 1.05 s after 3.95: also more
    tl = plan_timeline(np.concatenate([first, second, short]))
    assert len(tl.source_ranges) == 3
    assert tl.source_ranges[0] == (0, 19)
    starts = [int(np.flatnonzero(tl.segment == s)[0]) for s in range(3)]
    jumps = [int(tl.seq[i] - tl.seq[i - 1]) for i in starts[1:]]
    # The second segment starts 2.0625 s after the first one's last frame (0.9375 s):
    # round(2.0625 * 16) = 33 sequence numbers on, more than the daemon's restart gap.
    assert jumps[0] == 33
    assert all(j > WINDOW_RESTART_GAP_FRAMES for j in jumps)
    # A gap just within the restart gap does not split.
    t = np.r_[0.0, RESTART_GAP_S - 0.01]
    assert len(plan_timeline(t).source_ranges) == 1


def test_box_average_of_a_step_by_hand() -> None:
    t = np.arange(0, 64) / 64.0  # 64 Hz
    v = (t >= 0.5).astype(float)[:, None]  # 0 until 0.484375, then 1 from 0.5
    out = box_average(t, v, np.array([0.4375, 0.5, 0.5625]))[:, 0]
    # Around 0.5: [0.46875, 0.53125]; the ramp 0.484375..0.5 adds 1/128, the ones
    # 0.5..0.53125 add 1/32: (1/128 + 1/32) * 16 = 0.625.
    np.testing.assert_allclose(out, [0.0, 0.625, 1.0])


def test_box_average_keeps_a_line_and_clips_at_the_ends() -> None:
    t = np.arange(0, 17) / 8.0  # 8 Hz, slower than ours: linear interpolation
    v = np.stack([t, 2 * t + 1], axis=1)
    t_out = np.arange(1, 32) / 16.0
    out = box_average(t, v, t_out)
    np.testing.assert_allclose(out[:-1, 0], t_out[:-1], atol=1e-12)  # symmetric windows
    np.testing.assert_allclose(out[:-1, 1], 2 * t_out[:-1] + 1, atol=1e-12)
    # At t = 0 the window [-1/32, 1/32] is clipped to [0, 1/32]: its mean is 1/64.
    assert box_average(t, v, np.array([0.0]))[0, 0] == pytest.approx(1 / 64)
    # A single sample: its value everywhere.
    np.testing.assert_allclose(box_average(t[:1], v[:1], t_out[:3]), np.repeat(v[:1], 3, 0))


def test_keypoints_interpolate_and_mask_what_is_unknown() -> None:
    t = np.array([0.0, 0.1, 0.2, 0.6])
    points = np.zeros((4, 2, 3))
    points[:, 0, 0] = [0.0, 1.0, 2.0, 6.0]
    points[1, 1] = np.nan  # point 1 unseen at t = 0.1
    out = interpolate_points(t, points, np.array([0.05, 0.1, 0.15, 0.4, 0.7]), max_gap_s=0.25)
    np.testing.assert_allclose(out[:3, 0, 0], [0.5, 1.0, 1.5])
    assert np.isnan(out[0, 1]).all()  # a neighbour unseen
    assert not np.isnan(out[1, 0]).any()  # exactly at a sample
    assert np.isnan(out[3]).all()  # 0.2 .. 0.6 is a hole longer than max_gap_s
    assert np.isnan(out[4]).all()  # after the last sample


def running_integral_box_average(
    t: np.ndarray, values: np.ndarray, t_out: np.ndarray
) -> np.ndarray:
    """The box average as first written: the running integral of every sample, evaluated at
    each window's ends (the reference the weighted-band form must agree with)."""
    if t.size == 1:
        return np.repeat(np.asarray(values[:1], dtype=np.float64), t_out.size, axis=0)
    lo = np.maximum(t_out - 0.5 * PERIOD_S, t[0])
    hi = np.minimum(t_out + 0.5 * PERIOD_S, t[-1])
    v = np.asarray(values, dtype=np.float64)
    dt = np.diff(t)[:, None]
    cumulative = np.zeros_like(v)
    np.cumsum(0.5 * (v[1:] + v[:-1]) * dt, axis=0, out=cumulative[1:])
    slope = np.diff(v, axis=0) / dt

    def at(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        i = np.clip(np.searchsorted(t, x, side="right") - 1, 0, t.size - 2)
        dx = (x - t[i])[:, None]
        return i, dx, cumulative[i] + v[i] * dx + 0.5 * slope[i] * dx * dx

    i_lo, dx_lo, f_lo = at(lo)
    _, _, f_hi = at(hi)
    width = hi - lo
    point = width <= 0.0
    out = (f_hi - f_lo) / np.where(point, 1.0, width)[:, None]
    out[point] = (v[i_lo] + slope[i_lo] * dx_lo)[point]
    return np.asarray(out)


@pytest.mark.parametrize("rate", [5.0, 16.0, 33.3, 100.0, 1000.0])
def test_box_average_agrees_with_the_running_integral(rate: float) -> None:
    """Irregular clocks (bursts of near-equal stamps too), float32 and float64 values,
    windows clipped at both ends: the same means within float rounding."""
    rng = np.random.default_rng(int(rate))
    for trial in range(20):
        n = int(rng.integers(2, 2000))
        steps = rng.uniform(0.01, 1.99, n) / rate
        steps[rng.random(n) < 0.05] = 1e-6  # bursts: many samples under one window
        t = 1e4 + np.cumsum(steps)
        dtype = (np.float32, np.float64)[trial % 2]
        v = rng.uniform(0, 300, (n, int(rng.integers(1, 40)))).astype(dtype)
        t_out = t[0] + np.arange(int((t[-1] - t[0]) * 16) + 1) / 16 + rng.uniform(0, 1 / 16)
        t_out = t_out[t_out <= t[-1]]
        expected = running_integral_box_average(t, v, t_out)
        np.testing.assert_allclose(box_average(t, v, t_out), expected, rtol=1e-9, atol=1e-9)
    # A window past the last sample is clipped to nothing: the line's value at its start.
    t, v, past = np.array([0.0, 1.0]), np.array([[0.0], [2.0]]), np.array([1.0 + PERIOD_S])
    assert box_average(t, v, past)[0, 0] == pytest.approx(2.0 + PERIOD_S)
    np.testing.assert_allclose(box_average(t, v, past), running_integral_box_average(t, v, past))


def test_an_import_s_counts_are_those_of_the_running_integral(tmp_path: Path) -> None:
    """The whole path from source values to counts, on a table (a grid, with gaps that cut
    segments) and a vendor file of cells: every count as the reference average gives it."""
    t = np.r_[np.arange(0, 30, 0.0093), 32 + np.arange(0, 7, 0.0093)]  # 107.5 Hz, a 2 s gap
    frames = pressure_frames(t, 7, 5) + np.random.default_rng(3).uniform(0, 5, (t.size, 2, 7, 5))
    table = tmp_path / "p.csv"
    write_pressure_csv(table, t * 1000, frames)
    raw = {"rows": 7, "cols": 5, "time_unit": "ms", "file": str(table)}
    on_cells = frames[:3000, 0, :4, :4].reshape(-1, 16) / 10.0  # N/cm2, 100 Hz
    cells = write_moticon(tmp_path / "m.txt", np.arange(3000) * 0.01, {"left": on_cells})
    for cfg in (
        config_from_dict({"pressure": raw, "counts": {"method": "per_kpa", "units_per_kpa": 1.0}}),
        config_from_dict({"pressure": {"file": str(cells)}}),
    ):
        source = load_pressure(cfg).feet
        timeline = plan_timeline(source.times)
        expected = np.zeros((len(timeline), 2, FRAME_ROWS, FRAME_COLS), dtype=np.uint16)
        for index, (a, b) in enumerate(timeline.source_ranges):
            rows = timeline.segment == index
            means = running_integral_box_average(
                source.times[a : b + 1], source.values[a : b + 1], timeline.times[rows]
            )
            for foot in source.feet:
                counts = source.maps[foot](means[:, source.columns[foot]])
                expected[rows, FEET.index(foot)] = np.clip(np.rint(counts), 0, MAX_COUNT)
        assert len(timeline.source_ranges) == (2 if cfg.pressure.file == str(table) else 1)
        assert expected.any()
        np.testing.assert_array_equal(resample_feet(source, timeline), expected)
