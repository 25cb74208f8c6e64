"""Time: segments at gaps, sequence jumps, the box average and keypoint interpolation by hand."""

from __future__ import annotations

import numpy as np
import pytest
from scotti.importers.timebase import (
    RESTART_GAP_S,
    box_average,
    interpolate_points,
    plan_timeline,
)
from scotti.models.contract import WINDOW_RESTART_GAP_FRAMES


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
