"""What the input itself says before the model is asked: nobody there, or not a pressure map.

Two flags from simple statistics of the raw counts, each explainable to a
user and each measured on the simulated corpus (``python
experiments/ood_inputs.py``, figures in docs/ood.md):

- ``unloaded``: both feet together carry less than ``UNLOADED_FORCE_N``
  (nominal newtons, the counts turned back into kPa by the contract's
  transfer curve, models/insole.py, times a nominal taxel area) on every one
  of the newest ``UNLOADED_FRAMES`` frames. Nobody on the insoles, sitting,
  shoes off. A run that long rules out a jump's flight (a few tenths of a
  second).
- ``out_of_range``: at least ``OUT_OF_RANGE_FRAMES`` frames of the window are
  implausible as a plantar pressure map: load outside the insole's outline
  (no taxel there: the contract's input is zero), a quarter of a foot's
  taxels at the amplifier's rail, one taxel holding most of a foot's load,
  or more force than any landing. Saturated, noise-like and single-hot-taxel
  input trip one of these; one bad line (a corrupt row) does not. And one
  insole under ``FOOT_EMPTY_N`` for the whole window while the other carries
  the person: a dead insole, or a long one-legged stance, neither of which
  the model learnt (walking lifts a foot for well under a second).

Per-frame statistics are computed once per frame (``FrameCheck``, a few
microseconds) so the streaming window keeps the last T of them instead of
the frames. Numpy only (ARCHITECTURE.md, room ``models/``).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt
from scotti.models.contract import FRAME_COLS, FRAME_RATE_HZ, FRAME_ROWS, MAX_COUNT, WINDOW
from scotti.models.insole import DEFAULT_TRANSFER, Transfer, insole_mask

UNLOADED: Final = "unloaded"
OUT_OF_RANGE: Final = "out_of_range"

# A taxel is about 4 x 8 mm (sim/insole.py); the force of a frame is its pressures
# times this nominal area. Nominal: a real insole's taxels scale with its size.
TAXEL_AREA_M2: Final = 32e-6
# Both feet below this together: nobody stands on the insoles. About 10 kg; the
# lightest frame of the simulated corpus carries 257 N (docs/ood.md).
UNLOADED_FORCE_N: Final = 100.0
# ... for this many newest frames in a row (1 s): a jump's flight is shorter.
UNLOADED_FRAMES: Final = 16
# Share of a frame's counts on taxels outside the insole outline (corpus: 0; no
# taxel is there, so the contract's input is 0: simulator and importers mask it).
OUTSIDE_SHARE_MAX: Final = 0.01
# A taxel at the rail reads at least this (the realistic insole rails at 3800 counts).
RAIL_COUNTS: Final = 0.95 * DEFAULT_TRANSFER.saturation_counts
# Share of a foot's outline taxels at the rail (corpus: 0).
RAIL_SHARE_MAX: Final = 0.25
# Share of a foot's counts in its largest taxel (corpus: at most 0.47).
PEAK_SHARE_MAX: Final = 0.75
# Total nominal force of a frame (corpus: at most 3120 N, jump landings).
FORCE_MAX_N: Final = 8000.0
# Implausible frames in a window before it is flagged out_of_range (0.25 s).
OUT_OF_RANGE_FRAMES: Final = 4
# One foot under this on every frame of a full window (corpus: a foot carries >= 117 N).
FOOT_EMPTY_N: Final = 20.0


def input_check_thresholds() -> dict[str, float]:
    """The rules' thresholds by name, for model cards and ``info``."""
    return {
        "unloaded_force_n": UNLOADED_FORCE_N,
        "unloaded_frames": UNLOADED_FRAMES,
        "outside_share_max": OUTSIDE_SHARE_MAX,
        "rail_counts": RAIL_COUNTS,
        "rail_share_max": RAIL_SHARE_MAX,
        "peak_share_max": PEAK_SHARE_MAX,
        "force_max_n": FORCE_MAX_N,
        "out_of_range_frames": OUT_OF_RANGE_FRAMES,
        "foot_empty_n": FOOT_EMPTY_N,
        "taxel_area_m2": TAXEL_AREA_M2,
    }


_MASK: Final = insole_mask()  # (H, W) True where the insole has a taxel
_OUTSIDE: Final = np.concatenate([~_MASK, ~_MASK], axis=1)  # (H, 2W), left | right


def kpa_from_counts(
    counts: npt.ArrayLike, transfer: Transfer = DEFAULT_TRANSFER
) -> npt.NDArray[np.float64]:
    """The transfer curve turned round: counts -> kPa (0 for 0; the rail reads its pressure).

    ``counts = 4095 q^n / (q^n + p_half^n)`` gives ``q = p_half (c / (4095 - c))^(1/n)``
    and ``p = q + threshold``; counts above the rail are taken as the rail.
    """
    c = np.minimum(np.asarray(counts, dtype=np.float64), transfer.saturation_counts)
    c = np.clip(c, 0.0, MAX_COUNT - 1.0)
    pressed = c > 0.0
    q = transfer.p_half_kpa * (c / (MAX_COUNT - c)) ** (1.0 / transfer.exponent)
    return np.where(pressed, q + transfer.threshold_kpa, 0.0)


@dataclass(frozen=True)
class FrameCheck:
    """The statistics of one frame (H, 2W) the rules read, and the frame's verdict."""

    force_n: tuple[float, float]  # nominal force of the left and the right foot
    outside_share: float  # share of the counts outside the insole outline
    rail_share: float  # the larger of the two feet's share of outline taxels at the rail
    peak_share: float  # the larger of the two feet's share of counts in one taxel

    @property
    def loaded(self) -> bool:
        return sum(self.force_n) >= UNLOADED_FORCE_N

    @property
    def implausible(self) -> list[str]:
        """The rules this frame breaks, by name (empty: a plausible pressure map)."""
        broken = []
        if self.outside_share > OUTSIDE_SHARE_MAX:
            broken.append("load outside the insole outline")
        if self.rail_share > RAIL_SHARE_MAX:
            broken.append("taxels at the rail")
        if self.peak_share > PEAK_SHARE_MAX:
            broken.append("one taxel holds the load")
        if sum(self.force_n) > FORCE_MAX_N:
            broken.append("more force than a landing")
        return broken


def check_frame(counts: npt.ArrayLike) -> FrameCheck:
    """Statistics of one model input frame (H, 2W) of raw counts, left foot then right."""
    return check_frames(np.asarray(counts)[None])[0]


# kPa of every whole count (the curve turned round once, not per taxel and frame).
_KPA_OF_COUNT: Final = kpa_from_counts(np.arange(MAX_COUNT + 1))
_N_PER_KPA: Final = 1e3 * TAXEL_AREA_M2  # one kPa on one taxel, in newtons


def check_frames(frames: npt.ArrayLike) -> list[FrameCheck]:
    """``check_frame`` of N frames (N, H, 2W) at once (counts rounded to whole counts)."""
    s = frame_stats(frames)
    return [
        FrameCheck(
            (float(s.force_n[i, 0]), float(s.force_n[i, 1])),
            float(s.outside_share[i]),
            float(s.rail_share[i]),
            float(s.peak_share[i]),
        )
        for i in range(len(s.outside_share))
    ]


@dataclass(frozen=True)
class FrameStats:
    """``FrameCheck`` of N frames as arrays (the batched evaluation replay's form)."""

    force_n: npt.NDArray[np.float64]  # (N, 2) left, right
    outside_share: npt.NDArray[np.float64]  # (N,)
    rail_share: npt.NDArray[np.float64]  # (N,) the larger foot's
    peak_share: npt.NDArray[np.float64]  # (N,) the larger foot's

    @property
    def loaded(self) -> npt.NDArray[np.bool_]:
        """(N,) ``FrameCheck.loaded`` of each frame."""
        return np.asarray(self.force_n[:, 0] + self.force_n[:, 1] >= UNLOADED_FORCE_N)

    @property
    def implausible(self) -> npt.NDArray[np.bool_]:
        """(N,) whether ``FrameCheck.implausible`` names any rule for the frame."""
        return np.asarray(
            (self.outside_share > OUTSIDE_SHARE_MAX)
            | (self.rail_share > RAIL_SHARE_MAX)
            | (self.peak_share > PEAK_SHARE_MAX)
            | (self.force_n[:, 0] + self.force_n[:, 1] > FORCE_MAX_N)
        )


def frame_stats(frames: npt.ArrayLike) -> FrameStats:
    """The statistics of N frames (N, H, 2W) the rules read, as arrays."""
    x = np.asarray(frames, dtype=np.float64)
    if x.ndim != 3 or x.shape[1:] != (FRAME_ROWS, 2 * FRAME_COLS):
        msg = f"frames are (N, {FRAME_ROWS}, {2 * FRAME_COLS}), got {x.shape}"
        raise ValueError(msg)
    x = np.clip(np.nan_to_num(x, nan=0.0), 0.0, MAX_COUNT)
    n = x.shape[0]
    feet = x.reshape(n, FRAME_ROWS, 2, FRAME_COLS)  # (N, H, foot, W)
    kpa = _KPA_OF_COUNT[np.rint(feet).astype(np.intp)]
    force = kpa.sum(axis=(1, 3)) * _N_PER_KPA  # (N, 2)
    total = x.sum(axis=(1, 2))
    outside = np.where(total > 0, (x * _OUTSIDE).sum(axis=(1, 2)) / np.maximum(total, 1), 0.0)
    at_rail = (feet >= RAIL_COUNTS) & _MASK[None, :, None, :]
    rail = at_rail.sum(axis=(1, 3)) / _MASK.sum()  # (N, 2)
    sums = feet.sum(axis=(1, 3))
    peak = np.where(sums > 0, feet.max(axis=(1, 3)) / np.maximum(sums, 1), 0.0)  # (N, 2)
    return FrameStats(force, outside, rail.max(axis=1), peak.max(axis=1))


def window_flags(
    stats: FrameStats, window: int = WINDOW
) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.bool_]]:
    """``verdict``'s flags for every full window of consecutive frames, at once:
    (unloaded, out_of_range), each (N,), row j for the window of frames j-window+1..j
    (False for j < window - 1, where no full window ends)."""
    full = np.arange(len(stats.outside_share)) >= window - 1
    # The newest UNLOADED_FRAMES of the window (none: a window shorter than that).
    unloaded = _all_in(~stats.loaded, UNLOADED_FRAMES) & full & (window >= UNLOADED_FRAMES)
    bad = _count_in(stats.implausible, window) >= OUT_OF_RANGE_FRAMES
    force = stats.force_n
    empty = _all_in(force[:, 0] < FOOT_EMPTY_N, window) | _all_in(
        force[:, 1] < FOOT_EMPTY_N, window
    )
    return unloaded, (bad | (empty & ~unloaded)) & full


def _count_in(x: npt.NDArray[np.bool_], width: int) -> npt.NDArray[np.int64]:
    """(N,) how many of x[j-width+1 .. j] are True (fewer rows near the start)."""
    c = np.concatenate([[0], np.cumsum(x, dtype=np.int64)])
    return np.asarray(c[1:] - c[np.maximum(np.arange(1, len(c)) - width, 0)])


def _all_in(x: npt.NDArray[np.bool_], width: int) -> npt.NDArray[np.bool_]:
    """(N,) whether x[j-width+1 .. j] are all True (False where fewer than width rows)."""
    full = np.arange(len(x)) >= width - 1
    return np.asarray((_count_in(x, width) == width) & full)


@dataclass(frozen=True)
class WindowVerdict:
    """What the rules say about a window: flags and one reason line per flag."""

    flags: tuple[str, ...]  # UNLOADED and/or OUT_OF_RANGE, in that order
    reasons: tuple[str, ...]


def verdict(checks: Sequence[FrameCheck], window: int = WINDOW) -> WindowVerdict:
    """The rules over the frames of a window, oldest first (``window``: a full one's length)."""
    flags, reasons = [], []
    newest = list(checks)[-UNLOADED_FRAMES:]
    unloaded = len(newest) == UNLOADED_FRAMES and not any(c.loaded for c in newest)
    if unloaded:
        flags.append(UNLOADED)
        reasons.append(
            f"unloaded: both insoles under {UNLOADED_FORCE_N:.0f} N "
            f"for {UNLOADED_FRAMES / FRAME_RATE_HZ:g} s (nobody on them?)"
        )
    bad = [broken for broken in (c.implausible for c in checks) if broken]
    what = (
        sorted({name for broken in bad for name in broken})
        if len(bad) >= OUT_OF_RANGE_FRAMES
        else []
    )
    if len(checks) >= window and not unloaded:
        for side, foot in enumerate(("left", "right")):
            if all(c.force_n[side] < FOOT_EMPTY_N for c in checks):
                what.append(f"{foot} insole empty for the whole window")
    if what:
        # No counts in the text: status is republished whenever its reasons change.
        flags.append(OUT_OF_RANGE)
        reasons.append(f"out_of_range: not a plantar pressure map ({', '.join(what)})")
    return WindowVerdict(tuple(flags), tuple(reasons))


def check_window(frames: npt.ArrayLike) -> WindowVerdict:
    """The rules over a whole window (T, H, 2W) of raw counts (the window graph's input)."""
    checks = check_frames(frames)
    return verdict(checks, window=len(checks))


_CLEAR: Final = WindowVerdict((), ())


class FrameChecks:
    """The checks of the last ``size`` frames, for a streaming window.

    ``verdict`` walks every check of the window; run per frame and per device that
    was a sixth of the inference thread's time (py-spy, 16 pairs). The counts the
    rules need are kept up to date as frames come and go instead, and ``verdict``
    runs only when one of them says a rule may hold: the same verdicts, in O(1)
    for the windows nothing is wrong with.
    """

    def __init__(self, size: int) -> None:
        self._size = size
        self._checks: deque[FrameCheck] = deque(maxlen=size)
        self._bad: deque[bool] = deque(maxlen=size)  # implausible, per frame
        self._bad_count = 0
        self._empty_count = [0, 0]  # frames with the left, the right foot under FOOT_EMPTY_N
        self._unloaded_run = 0  # newest frames in a row that are not loaded

    def push(self, counts: npt.ArrayLike) -> WindowVerdict:
        return self.push_check(check_frame(counts))

    def push_check(self, check: FrameCheck) -> WindowVerdict:
        """Take a frame's check made elsewhere (``check_frames`` of a batch of frames)."""
        if len(self._checks) == self._size and self._size > 0:
            old = self._checks[0]
            self._bad_count -= self._bad[0]
            for side in (0, 1):
                self._empty_count[side] -= old.force_n[side] < FOOT_EMPTY_N
        bad = bool(check.implausible)
        self._checks.append(check)
        self._bad.append(bad)
        self._bad_count += bad
        for side in (0, 1):
            self._empty_count[side] += check.force_n[side] < FOOT_EMPTY_N
        self._unloaded_run = 0 if check.loaded else self._unloaded_run + 1
        held = len(self._checks)
        maybe = (
            self._unloaded_run >= UNLOADED_FRAMES
            or self._bad_count >= OUT_OF_RANGE_FRAMES
            or (held >= self._size and held in self._empty_count)
        )
        return verdict(self._checks, self._size) if maybe else _CLEAR

    def reset(self) -> None:
        self._checks.clear()
        self._bad.clear()
        self._bad_count = 0
        self._empty_count = [0, 0]
        self._unloaded_run = 0
