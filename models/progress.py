"""Progress labels: how far through one repetition each frame is, 0..1.

Han et al. (SCOTTI) define progress from a per-action indicator h(t) of the
3D pose. Repetitions are cut at the peaks of h; inside one repetition, with
hmax and hmin its extremes and "mid" the frame where h is smallest,

    p(t) = 0.5 (hmax - h) / (hmax - hmin)          from the start to the mid
    p(t) = 0.5 + 0.5 (h - hmin) / (hmax - hmin)    from the mid to the end

so p runs 0 -> 0.5 -> 1 as h goes top -> bottom -> top.

Which frames carry which action (a pause between repetitions is its set's
for a second, standing beyond that and at a set's edges is ``standing``, transitions
``NO_ACTION``) is the labelling convention in models/contract.py, the same
for every source of labels; this module labels progress inside the runs of
actions it is given.

Choices the paper leaves open, fixed here:
- Repetitions are cut where the person rests between them, which must be a
  peak of h. Squats and lunges rest standing tall: h is the mid-hip height.
- A flat top (a pause between repetitions) is cut at its first frame, the
  moment the person arrives: the pause belongs to the repetition that
  follows it, at progress ~0, and the repetition just finished is complete
  (counted) on arrival. Cutting at the top's middle, as a plain peak finder
  does, split every pause at a point nothing in the input shows: the same
  standing-tall frames were labelled 1 before it and 0 after, and a model
  could only answer 0.5 there (on the first corpus, frames within 0.1 of
  0 or 1 were 40 % of the labelled frames and 77 % of the squared error).
  Jumps rest in the crouch and step-ups on the floor, at the bottom of the
  mid-hip height: for them h is its negative, so a step-up runs floor (0) ->
  on the step (0.5) -> floor (1). With h = +height, K step-ups have K peaks
  (one per stand on the step) and were cut into K + 1 pieces.
- A run that ends resting at the top (standing tall after the last squat,
  back on the floor after the last step-up) is cut where that last rest
  begins, like every rest before it: the final rest reads ~0, and the last
  repetition is complete on arrival. Left in the trailing segment, the same
  standing frames read 1 after the last repetition and 0 after every other
  (12-37 % of the squared error of a trained model on squats, step-ups and
  lunges was on such frames).
- Walking in place's h is minus the higher heel's height (a step runs double
  support -> the swing's top, 0.5 -> double support), not the paper's +height,
  whose peaks fall in the middle of single support, which the pressure maps do
  not mark (3.2 frames before the next foot strike, spread 0.9).
- Walking, walking backward and walking in place are cut on the frame after
  a foot lands (``PeakParams.step_cut = "after_landing"``; ``run_progress``,
  models/touchdown.py ``step_starts``), the first frame whose prediction sees
  the landing: the model predicts frame t from frames t-T..t-1. h's peaks
  (``step_cut = "peak"``, the convention before 2026-12-01) fall half a frame
  after the landing for walking (on its frame or the next, by the sampling's
  luck) and 1.5 frames before it for walking backward, and a model trained on
  them hedged at 0.5 there (three quarters of walking's squared progress
  error; `python experiments/progress_error_sites.py`); cut on the landing
  frame itself, a model trained so hedged one frame earlier. The cuts fall +0.96
  frames after the insole first loads (spread 0.18; `python
  experiments/label_cuts.py data/corpus21/realistic/subject-013.ses
  --strike-share 0.05`). Within a step, h gives the values, rescaled to start
  at 0 on the cut and held from h's top to the next cut (``rise_from_cut``).
  Side walking keeps h's peaks (its two-step cycle is not hedged: APP 0.95).
- Peaks are found on h smoothed by a short moving average, with a minimum
  prominence (a share of the run's range, and an absolute floor in metres)
  and a minimum distance in frames (``PeakParams``). Values of p use raw h.
- A complete repetition runs from one cut to the next; its hmax/hmin include
  both cut frames.
- The segments before the first cut and after the last are partial (the run
  starts or ends mid-repetition). Their hmax is the larger of their own and
  the nearest complete repetition's; their hmin is their own when their
  minimum lies strictly inside them (the bottom was seen), else the smaller
  of their own and the nearest complete repetition's. With no complete
  repetition, a segment uses its own extremes.
- A flat segment (hmax - hmin < ``FLAT_RANGE``) gets p = 0.5 everywhere: no
  movement, no evidence of progress, and no repetition to count.
- Non-finite h (NaN keypoints) is filled from the nearest finite frames; an
  all-NaN run is flat. Output is always finite and clipped to [0, 1].
- Only repeated actions (``contract.REPEATED_ACTIONS``) have an indicator.
  Standing runs no repetition: its frames, like transitions (``NO_ACTION``),
  get NaN progress and repetition -1.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Final, NamedTuple

import numpy as np
import numpy.typing as npt
from scotti.models.contract import (
    ACTIONS,
    KP,
    NO_ACTION,
    NUM_ACTIONS,
    NUM_KEYPOINTS,
    has_progress,
)
from scotti.models.errors import ModelInputError
from scotti.models.touchdown import TOUCHDOWN_CUT, rise_from_cut, step_starts

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

# A segment whose indicator spans less than this (metres) is flat.
FLAT_RANGE = 1e-6
# backward_walking: heel displacement over this many frames.
BACKWARD_LAG = 5


@dataclass(frozen=True)
class PeakParams:
    """How repetition cuts are found on the indicator (defaults suit 16 Hz)."""

    smooth_frames: int = 3  # moving-average width before peak finding (1 = none)
    # A pause at a peak: the frames before it that stay within ``top_share`` of
    # the peak's prominence (at least ``top_tolerance`` metres) of its height,
    # for ``min_pause_frames`` or more; the cut moves to the first of them.
    # Shorter tops are smooth turns, not rests: their cut stays at the peak.
    # The band is wide enough for the hips' sway on arrival (5-9 mm after a step down
    # in the simulator): at 3 % / 2 mm a step-up's rest on the floor was cut half-way,
    # its first half read ~1 and its second ~0, and a model could only answer 0.5.
    top_share: float = 0.08
    top_tolerance: float = 0.005
    min_pause_frames: int = 4
    min_distance: int = 4  # frames between two cuts: 0.25 s, faster than any step
    rel_prominence: float = 0.25  # share of the smoothed run's range
    abs_prominence: float = 1e-3  # metres: a smaller wiggle is noise, not a repetition
    # Where the stepping actions of touchdown.TOUCHDOWN_CUT start a step (STEP_CUTS).
    step_cut: str = "after_landing"


# How walking, walking backward and walking in place are cut into steps:
# "after_landing", on the frame after each landing (the convention in force: the
# shipped model was trained on it, docs/generalisation.md "Steps cut after the
# landing"); "peak", at the indicator's peaks (the convention before; `scotti session
# relabel --step-cut peak` writes a corpus so, for models trained on it).
STEP_CUTS: Final = ("peak", "after_landing")


class ProgressLabels(NamedTuple):
    """Per-frame labels; unpacks as ``progress, repetition = label_progress(...)``."""

    progress: npt.NDArray[np.float32]  # (N,) in [0, 1], NaN where the action has none
    repetition: npt.NDArray[np.int32]  # (N,) index within the action's run, -1 where none


def progress_indicator(keypoints: npt.ArrayLike, action: int) -> FloatArray:
    """The indicator h(t) for one action: (N, 19, 3) metres -> (N,); the paper's, with the
    signs chosen in the module docstring."""
    k = _check_keypoints(keypoints)
    if not has_progress(action):
        shown = ACTIONS[action] if 0 <= action < NUM_ACTIONS else action
        msg = f"action {shown} has no progress indicator (it runs no repetitions)"
        raise ModelInputError(msg)
    name = ACTIONS[action]
    heels = k[:, [KP["left_heel"], KP["right_heel"]], :]  # (N, 2, 3)
    if name in ("squat", "lunge", "step_up", "jump"):
        mid_hip_z = 0.5 * (k[:, KP["left_hip"], 2] + k[:, KP["right_hip"], 2])
        return -mid_hip_z if name in ("jump", "step_up") else mid_hip_z
    if name in ("walking", "side_walking"):
        return np.asarray(np.linalg.norm(heels[:, 0] - heels[:, 1], axis=-1), np.float64)
    if name == "in_place_walking":  # negated: cut with both feet down (module docstring)
        return np.asarray(-heels[:, :, 2].max(axis=1), np.float64)
    # backward_walking: max over both heels of |heel(t) - heel(t - 5)|; the first
    # frames compare with frame 0, the oldest one available.
    earlier = np.maximum(np.arange(len(k)) - BACKWARD_LAG, 0)
    moved = np.linalg.norm(heels - heels[earlier], axis=-1)  # (N, 2)
    return np.asarray(moved.max(axis=1), np.float64)


def find_peaks(h: npt.ArrayLike, *, min_distance: int = 1, min_prominence: float = 0.0) -> IntArray:
    """Indices of the local maxima of ``h`` (ascending) that pass both filters.

    Flat tops count once, at their middle; the first and last samples are never
    peaks. Prominence as usual: the height above the higher of the two lowest
    points reached before meeting a higher sample (or the border) on each side.
    Of two peaks closer than ``min_distance``, the higher is kept.
    """
    x = np.asarray(h, dtype=np.float64)
    peaks = _local_maxima(x)
    if peaks.size == 0:
        return peaks
    prominence = np.array([_prominence(x, int(p)) for p in peaks])
    peaks = peaks[prominence >= min_prominence]
    if min_distance > 1 and peaks.size > 1:
        peaks = _keep_distant(x, peaks, min_distance)
    return peaks


def repetition_cuts(h: npt.ArrayLike, params: PeakParams = PeakParams()) -> IntArray:
    """Frames where a new repetition starts: the prominent peaks of smoothed h."""
    return _cuts(_finite(np.asarray(h, dtype=np.float64)), params)[0]


def progress_from_indicator(
    h: npt.ArrayLike, params: PeakParams = PeakParams(), cuts: npt.ArrayLike | None = None
) -> tuple[FloatArray, IntArray]:
    """Progress (N,) in [0, 1] and repetition index (N,) for one run of one action.

    ``cuts``: where repetitions start (ascending frames inside the run, never 0),
    the touch-downs of a stepping action; None cuts at the indicator's peaks.
    With given cuts a repetition starts at 0 on its cut and its progress never
    falls before the next: the indicator's top need not sit on a cut (walking
    backward's lies 2.5 frames before it), so the indicator's value on the cut
    is the new step's 0 and what follows its top is the step's end, 1.
    """
    x = _finite(np.asarray(h, dtype=np.float64))
    n = x.size
    progress = np.full(n, 0.5)
    repetition = np.zeros(n, dtype=np.int64)
    if n == 0:
        return progress, repetition
    given = cuts is not None
    if cuts is None:
        cuts, final_rest = _cuts(x, params)
    else:
        cuts, final_rest = np.asarray(cuts, dtype=np.int64), False
    bounds = [0, *cuts.tolist(), n]
    first_complete = (int(cuts[0]), int(cuts[1])) if cuts.size >= 2 else None
    last_complete = (int(cuts[-2]), int(cuts[-1])) if cuts.size >= 2 else None
    for index, (start, end) in enumerate(itertools.pairwise(bounds)):
        repetition[start:end] = index
        leading, trailing = index == 0, index == len(bounds) - 2
        mid = None  # the segment's minimum
        if not (leading or trailing):
            # Complete: from one cut up to and including the next.
            top, bottom = _extremes(x[start : end + 1])
        elif trailing and final_rest:
            # The run's last rest: the start of a repetition that never goes down.
            # Its own sway is no bottom: the last repetition's extremes, and the
            # descending branch throughout, so that it reads ~0 like every rest.
            before = last_complete or (0, start)  # a lone repetition: the one before
            top, bottom = _partial_extremes(x, start, end, before, bottom_seen=False)
            mid = end - start - 1
        else:
            reference = first_complete if leading else last_complete
            top, bottom = _partial_extremes(x, start, end, reference)
        segment = _segment_progress(x[start:end], top, bottom, mid)
        if given:
            segment = rise_from_cut(segment, starts_at_cut=not leading)
        progress[start:end] = segment
    return progress, repetition


def run_progress(
    keypoints: npt.ArrayLike, action: int, params: PeakParams = PeakParams()
) -> tuple[FloatArray, IntArray]:
    """Progress and repetition of one run of one repeated action, by the labelling
    convention: the indicator's peaks; with ``params.step_cut = "after_landing"`` the
    stepping actions of ``touchdown.TOUCHDOWN_CUT`` on the frame after each landing
    (where the feet cannot be read, or land fewer than twice, at the peaks)."""
    if params.step_cut not in STEP_CUTS:
        msg = f"step_cut {params.step_cut!r} is not one of {', '.join(STEP_CUTS)}"
        raise ModelInputError(msg)
    h = progress_indicator(keypoints, action)
    cuts = None
    if params.step_cut == "after_landing" and action in TOUCHDOWN_CUT:
        starts = step_starts(keypoints, params.min_distance)
        if starts is not None and starts.size >= 2:
            cuts = starts
    return progress_from_indicator(h, params, cuts)


def label_progress(
    keypoints: npt.ArrayLike, actions: npt.ArrayLike, params: PeakParams = PeakParams()
) -> ProgressLabels:
    """Label every frame of a session, one contiguous run of one action at a time.

    ``keypoints`` (N, 19, 3) metres, ``actions`` (N,) ints, ``NO_ACTION`` for
    transitions. Repetitions are counted from 0 within each run of a repeated
    action; standing and transitions get NaN progress and repetition -1.
    """
    k = _check_keypoints(keypoints)
    a = np.asarray(actions)
    if a.shape != (len(k),) or not np.issubdtype(a.dtype, np.integer):
        msg = f"actions must be ({len(k)},) integers, got {a.shape} {a.dtype}"
        raise ModelInputError(msg)
    bad = (a != NO_ACTION) & ((a < 0) | (a >= NUM_ACTIONS))
    if bad.any():
        msg = f"action {int(a[bad][0])} is neither NO_ACTION nor 0..{NUM_ACTIONS - 1}"
        raise ModelInputError(msg)
    progress = np.full(len(k), np.nan, dtype=np.float32)
    repetition = np.full(len(k), -1, dtype=np.int32)
    for start, end in _runs(a):
        action = int(a[start])
        if not has_progress(action):
            continue
        progress[start:end], repetition[start:end] = run_progress(k[start:end], action, params)
    return ProgressLabels(progress, repetition)


# --- helpers ---------------------------------------------------------------


def _check_keypoints(keypoints: npt.ArrayLike) -> FloatArray:
    k = np.asarray(keypoints, dtype=np.float64)
    if k.ndim != 3 or k.shape[1:] != (NUM_KEYPOINTS, 3):
        msg = f"keypoints must be (N, {NUM_KEYPOINTS}, 3), got {k.shape}"
        raise ModelInputError(msg)
    return k


def _runs(values: npt.NDArray[np.integer]) -> list[tuple[int, int]]:
    """[start, end) of each maximal run of equal values."""
    if values.size == 0:
        return []
    starts = np.flatnonzero(np.r_[True, values[1:] != values[:-1]])
    ends = np.r_[starts[1:], values.size]
    return list(zip(starts.tolist(), ends.tolist(), strict=True))


def _finite(x: FloatArray) -> FloatArray:
    """Fill non-finite samples from their finite neighbours (all bad -> zeros)."""
    ok = np.isfinite(x)
    if ok.all():
        return x
    if not ok.any():
        return np.zeros_like(x)
    index = np.arange(x.size)
    return np.interp(index, index[ok], x[ok])


def _moving_average(x: FloatArray, width: int) -> FloatArray:
    """Centred moving average; the borders repeat the edge samples."""
    if width <= 1 or x.size < 2:
        return x
    half = width // 2
    padded = np.pad(x, (half, width - 1 - half), mode="edge")
    return np.convolve(padded, np.full(width, 1.0 / width), mode="valid")


def _local_maxima(x: FloatArray) -> IntArray:
    """Strict local maxima; a flat top counts once, at its middle."""
    if x.size < 3:
        return np.zeros(0, dtype=np.int64)
    # Collapse runs of equal samples, find maxima there, map back to run middles.
    starts = np.flatnonzero(np.r_[True, x[1:] != x[:-1]])
    ends = np.r_[starts[1:] - 1, x.size - 1]
    v = x[starts]
    inner = np.flatnonzero((v[1:-1] > v[:-2]) & (v[1:-1] > v[2:])) + 1
    return np.asarray((starts[inner] + ends[inner]) // 2, dtype=np.int64)


def _pause_starts(x: FloatArray, peaks: IntArray, params: PeakParams) -> IntArray:
    """Each peak that ends a pause moved back to the pause's first frame.

    Never past the previous cut, and the first sample is never a cut.
    """
    cuts = peaks.copy()
    floor = 1
    for i, peak in enumerate(peaks.tolist()):
        level = x[peak] - max(params.top_tolerance, params.top_share * _prominence(x, peak))
        start = peak
        while start - 1 >= floor and x[start - 1] >= level:
            start -= 1
        if peak - start + 1 >= params.min_pause_frames:
            cuts[i] = start
        floor = peak + 1
    return cuts


def _cuts(x: FloatArray, params: PeakParams) -> tuple[IntArray, bool]:
    """Repetition cuts of a finite run, and whether the last one starts the run's final rest."""
    smooth = _moving_average(x, params.smooth_frames)
    span = float(smooth.max() - smooth.min()) if smooth.size else 0.0
    min_prominence = max(params.abs_prominence, params.rel_prominence * span)
    peaks = find_peaks(smooth, min_distance=params.min_distance, min_prominence=min_prominence)
    cuts = _pause_starts(smooth, peaks, params)
    final = _final_pause(smooth, cuts, params, min_prominence) if smooth.size else None
    return (cuts, False) if final is None else (np.append(cuts, final), True)


def _final_pause(
    x: FloatArray, cuts: IntArray, params: PeakParams, min_prominence: float
) -> int | None:
    """First frame of the rest at the top that ends the run, if it ends in one.

    A peak needs a descent after it, so a run's last rest is never one; it is
    a rest all the same when the last ``min_pause_frames`` or more frames stay
    within ``_pause_starts``'s band of the end, and the end stands at least
    ``min_prominence`` above the lowest point since the last cut.
    """
    after = int(cuts[-1]) if cuts.size else 0
    prominence = float(x[-1] - x[after:].min())
    if prominence < min_prominence:
        return None
    level = x[-1] - max(params.top_tolerance, params.top_share * prominence)
    start = x.size - 1
    while start - 1 > after and x[start - 1] >= level:
        start -= 1
    long_enough = x.size - start >= params.min_pause_frames
    return start if long_enough and start - after >= params.min_distance else None


def _prominence(x: FloatArray, peak: int) -> float:
    height = x[peak]
    higher_left = np.flatnonzero(x[:peak] > height)
    left = int(higher_left[-1]) + 1 if higher_left.size else 0
    higher_right = np.flatnonzero(x[peak + 1 :] > height)
    right = peak + int(higher_right[0]) if higher_right.size else x.size - 1
    base = max(x[left : peak + 1].min(), x[peak : right + 1].min())
    return float(height - base)


def _keep_distant(x: FloatArray, peaks: IntArray, min_distance: int) -> IntArray:
    """Greedy by height (earlier first on ties): drop peaks too near a kept one."""
    order = sorted(range(peaks.size), key=lambda i: (-x[peaks[i]], peaks[i]))
    keep = np.ones(peaks.size, dtype=bool)
    for i in order:
        if keep[i]:
            near = np.abs(peaks - peaks[i]) < min_distance
            near[i] = False
            keep[near] = False
    return peaks[keep]


def _extremes(h: FloatArray) -> tuple[float, float]:
    return float(h.max()), float(h.min())


def _partial_extremes(
    x: FloatArray,
    start: int,
    end: int,
    reference: tuple[int, int] | None,
    bottom_seen: bool | None = None,
) -> tuple[float, float]:
    """hmax/hmin of a segment cut off by the start or the end of the run; its bottom
    counts as seen (default) when its minimum lies strictly inside it."""
    own = x[start:end]
    top, bottom = _extremes(own)
    if reference is None:
        return top, bottom
    ref_top, ref_bottom = _extremes(x[reference[0] : reference[1] + 1])
    if bottom_seen is None:
        bottom_seen = 0 < int(own.argmin()) < own.size - 1
    return max(top, ref_top), bottom if bottom_seen else min(bottom, ref_bottom)


def _segment_progress(
    h: FloatArray, top: float, bottom: float, mid: int | None = None
) -> FloatArray:
    """The paper's two branches around ``mid`` (default: the segment's minimum), clipped
    to [0, 1]."""
    span = top - bottom
    if span < FLAT_RANGE:
        return np.full(h.size, 0.5)
    mid = int(h.argmin()) if mid is None else mid
    p = np.empty(h.size)
    p[: mid + 1] = 0.5 * (top - h[: mid + 1]) / span
    p[mid + 1 :] = 0.5 + 0.5 * (h[mid + 1 :] - bottom) / span
    return np.clip(p, 0.0, 1.0)
