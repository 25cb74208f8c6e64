"""Any frame rate onto the contract's 16 Hz, keeping the source's own clock.

The source's time stamps are cut into segments wherever two frames are more
than the contract's restart gap apart (``WINDOW_RESTART_GAP_FRAMES`` at
16 Hz, 1 s): the daemon restarts its window there, so the session does too
(its sequence numbers jump by more than that gap). Each segment gets frames
every 1/16 s from its first time stamp to its last, on the source's clock:
the session's packet and label times are the source's own time stamps.

Pressure is resampled by the mean of the source over each output frame's
period (the piecewise-linear source integrated over t +- 1/32 s, clipped
to the segment): a box filter when the source is faster than 16 Hz (no
aliasing, the sensor integrates too) and linear interpolation, slightly
smoothed, when it is slower. Keypoints are interpolated linearly at the
frame time; a point stays masked (NaN) where either neighbour is, or where
tracking has a hole longer than ``max_gap_s``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from scotti.models.contract import FRAME_RATE_HZ, WINDOW_RESTART_GAP_FRAMES

PERIOD_S: Final = 1.0 / FRAME_RATE_HZ
RESTART_GAP_S: Final = WINDOW_RESTART_GAP_FRAMES / FRAME_RATE_HZ  # a longer gap splits
# A gap's sequence jump: as many frames as the gap lasts, at least enough for
# readers to see a restart, at most this (far below the u16 wrap's half).
MAX_SEQ_JUMP: Final = 4096
_CHUNK: Final = 256  # output frames resampled at once (16 s: the samples stay in cache)
_MAX_GATHERED: Final = 1 << 21  # source values copied at once for the windows' weighted sums


@dataclass(frozen=True)
class Timeline:
    """The output frames: their times (source clock, seconds) and sequence numbers."""

    times: np.ndarray  # (M,) float64
    seq: np.ndarray  # (M,) int64, unwrapped; +1 per frame, a jump at every gap
    segment: np.ndarray  # (M,) int32
    source_ranges: list[tuple[int, int]]  # per segment, [first, last] source index

    def __len__(self) -> int:
        return int(self.times.size)


def plan_timeline(t: np.ndarray) -> Timeline:
    """Output frames for strictly increasing source times ``t`` (seconds)."""
    breaks = np.flatnonzero(np.diff(t) > RESTART_GAP_S) + 1
    starts = np.r_[0, breaks]
    ends = np.r_[breaks - 1, t.size - 1]
    times, seqs, segs = [], [], []
    next_seq = 0
    last_time: float | None = None
    for index, (a, b) in enumerate(zip(starts.tolist(), ends.tolist(), strict=True)):
        count = int(np.floor((t[b] - t[a]) * FRAME_RATE_HZ + 1e-9)) + 1
        seg_times = t[a] + np.arange(count) / FRAME_RATE_HZ
        if last_time is not None:
            gap_frames = round((seg_times[0] - last_time) * FRAME_RATE_HZ)
            next_seq += min(max(gap_frames, WINDOW_RESTART_GAP_FRAMES + 1), MAX_SEQ_JUMP) - 1
        times.append(seg_times)
        seqs.append(next_seq + np.arange(count, dtype=np.int64))
        segs.append(np.full(count, index, dtype=np.int32))
        next_seq += count
        last_time = float(seg_times[-1])
    return Timeline(
        times=np.concatenate(times),
        seq=np.concatenate(seqs),
        segment=np.concatenate(segs),
        source_ranges=list(zip(starts.tolist(), ends.tolist(), strict=True)),
    )


def box_average(t: np.ndarray, values: np.ndarray, t_out: np.ndarray) -> np.ndarray:
    """Mean of the piecewise-linear signal (t, values) over t_out +- PERIOD_S / 2.

    ``t`` (n,) increasing, ``values`` (n, D); the window is clipped to
    [t[0], t[-1]]. Returns (len(t_out), D) float64. One sample: its value.
    Works a chunk of output frames at a time, on the source samples under
    that chunk only, so memory stays small whatever the recording's length.
    """
    n = t.size
    out = np.empty((t_out.size, values.shape[1]))
    if n == 1:
        out[:] = np.asarray(values[0], dtype=np.float64)
        return out
    for s in range(0, t_out.size, _CHUNK):
        c = t_out[s : s + _CHUNK]
        lo = np.maximum(c - 0.5 * PERIOD_S, t[0])
        hi = np.minimum(c + 0.5 * PERIOD_S, t[-1])
        first = max(int(np.searchsorted(t, lo.min(), side="right")) - 1, 0)
        last = min(int(np.searchsorted(t, hi.max(), side="right")), n - 1)
        first = min(first, last - 1)
        out[s : s + _CHUNK] = _window_means(t[first : last + 1], values[first : last + 1], lo, hi)
    return out


def _window_means(t: np.ndarray, v: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Means of the piecewise-linear (t, v) over [lo, hi] (a point where hi <= lo).

    Each mean is a weighted sum of the few samples under its window (a band
    of the source), so it is computed as one: the weights per window, then
    the samples each window starts at gathered as a sliding window and summed
    against them, a bounded number of windows at a time. The weights come
    from the integral up to x in piece i (t[i] <= x < t[i + 1], dx = x - t[i]),

        F(x) = P[i] + v[i] (h[i - 1] + dx - b) + v[i + 1] b,   b = dx^2 / (2 dt[i]),

    with dt[i] = t[i + 1] - t[i], h = dt / 2 (h[-1] = 0) and P[i] the sum of
    v[m] (h[m - 1] + h[m]) over m < i (every sample weighted by the half
    pieces beside it): F(hi) - F(lo) weighs the samples from lo's piece up
    to hi's by those halves, and the four samples at the ends by the rest.
    """
    dt = np.diff(t)
    half = 0.5 * dt
    weight = np.zeros(t.size)
    weight[:-1] = half
    weight[1:] += half
    half_before = np.r_[0.0, half]
    i_lo, dx_lo = _locate(t, lo)
    i_hi, dx_hi = _locate(t, hi)
    band = int((i_hi - i_lo).max()) + 2  # samples under the widest window, and one beyond
    start = np.minimum(i_lo, t.size - band)  # the band stays inside the samples
    j = start[:, None] + np.arange(band)
    w = np.where((j >= i_lo[:, None]) & (j < i_hi[:, None]), weight[j], 0.0)
    rows = np.arange(lo.size)
    b_hi = dx_hi * dx_hi / (2.0 * dt[i_hi])
    b_lo = dx_lo * dx_lo / (2.0 * dt[i_lo])
    w[rows, i_hi - start] += half_before[i_hi] + dx_hi - b_hi
    w[rows, i_hi + 1 - start] += b_hi
    w[rows, i_lo - start] -= half_before[i_lo] + dx_lo - b_lo
    w[rows, i_lo + 1 - start] -= b_lo
    width = hi - lo
    point = width <= 0.0  # a window squeezed to nothing: the value at the point
    w /= np.where(point, 1.0, width)[:, None]
    if point.any():
        at = dx_lo[point] / dt[i_lo[point]]
        w[point] = 0.0
        w[rows[point], (i_lo - start)[point]] = 1.0 - at
        w[rows[point], (i_lo + 1 - start)[point]] = at
    windows = sliding_window_view(v, band, axis=0)  # (samples, D, band), a view
    out = np.empty((lo.size, v.shape[1]))
    step = max(1, _MAX_GATHERED // (band * v.shape[1]))
    for a in range(0, lo.size, step):
        b = a + step
        np.einsum("mdk,mk->md", windows[start[a:b]], w[a:b], out=out[a:b])
    return out


def _locate(t: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index of the linear piece holding each x, and x's offset into it."""
    i = np.clip(np.searchsorted(t, x, side="right") - 1, 0, t.size - 2)
    return i, x - t[i]


def interpolate_points(
    t: np.ndarray, points: np.ndarray, t_out: np.ndarray, max_gap_s: float
) -> np.ndarray:
    """Linear interpolation of (n, K, 3) points at ``t_out``; NaN where it cannot be trusted.

    NaN outside [t[0], t[-1]], between samples more than ``max_gap_s``
    apart, and where a neighbour with a non-zero weight is NaN.
    """
    n = t.size
    out = np.full((t_out.size, *points.shape[1:]), np.nan)
    if n == 0:
        return out
    i = np.searchsorted(t, t_out, side="right") - 1
    exact = (i >= 0) & (t[np.clip(i, 0, n - 1)] == t_out)
    inside = (i >= 0) & (i < n - 1)
    j = np.clip(i, 0, max(n - 2, 0))
    if n >= 2:
        gap = t[j + 1] - t[j]
        w = ((t_out - t[j]) / np.where(gap > 0, gap, 1.0))[:, None, None]
        mixed = (1.0 - w) * points[j] + w * points[j + 1]
        ok = inside & (gap <= max_gap_s)
        out[ok] = mixed[ok]
    hit = np.clip(i, 0, n - 1)
    out[exact] = points[hit[exact]]
    return out
