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

import functools
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


# The rules a frame can break, by name, in the order ``FrameCheck.implausible`` lists
# them; bit k of ``FrameStats.rule_bits`` is rule k.
RULES: Final = (
    "load outside the insole outline",
    "taxels at the rail",
    "one taxel holds the load",
    "more force than a landing",
)


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
    def rule_bits(self) -> int:
        """Bit k set when the frame breaks ``RULES[k]``."""
        return (
            (self.outside_share > OUTSIDE_SHARE_MAX)
            | (self.rail_share > RAIL_SHARE_MAX) << 1
            | (self.peak_share > PEAK_SHARE_MAX) << 2
            | (sum(self.force_n) > FORCE_MAX_N) << 3
        )

    @property
    def implausible(self) -> list[str]:
        """The rules this frame breaks, by name (empty: a plausible pressure map)."""
        return _rule_names(self.rule_bits)


# For each value of the rule bits, the rules it sets (a frame's, counted in and out).
_RULES_IN: Final = tuple(
    tuple(k for k in range(len(RULES)) if bits >> k & 1) for bits in range(1 << len(RULES))
)


def _rule_names(bits: int) -> list[str]:
    return [name for k, name in enumerate(RULES) if bits >> k & 1]


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
        FrameCheck((force[0], force[1]), outside, rail, peak)
        for force, outside, rail, peak in zip(
            s.force_n.tolist(),
            s.outside_share.tolist(),
            s.rail_share.tolist(),
            s.peak_share.tolist(),
            strict=True,
        )
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
    def rule_bits(self) -> npt.NDArray[np.int64]:
        """(N,) ``FrameCheck.rule_bits`` of each frame."""
        bits = (self.outside_share > OUTSIDE_SHARE_MAX).astype(np.int64)
        bits |= (self.rail_share > RAIL_SHARE_MAX).astype(np.int64) << 1
        bits |= (self.peak_share > PEAK_SHARE_MAX).astype(np.int64) << 2
        bits |= (self.force_n[:, 0] + self.force_n[:, 1] > FORCE_MAX_N).astype(np.int64) << 3
        return bits

    @property
    def implausible(self) -> npt.NDArray[np.bool_]:
        """(N,) whether ``FrameCheck.implausible`` names any rule for the frame."""
        return np.asarray(self.rule_bits != 0)

    def codes(self) -> tuple[list[int], list[bool], list[bool], list[bool]]:
        """What ``FrameChecks.push_code`` takes, per frame as Python lists (one conversion
        per batch, not one per frame and statistic): rule bits, loaded, left foot empty,
        right foot empty."""
        force = self.force_n
        return (
            self.rule_bits.tolist(),
            self.loaded.tolist(),
            (force[:, 0] < FOOT_EMPTY_N).tolist(),
            (force[:, 1] < FOOT_EMPTY_N).tolist(),
        )


_MASK_FLAT: Final = _MASK.ravel()  # one foot's taxels, row by row
_OUTSIDE_TAXELS: Final = np.flatnonzero(~_MASK_FLAT)
_OUTLINE_TAXELS: Final = int(_MASK.sum())


def frame_stats(frames: npt.ArrayLike) -> FrameStats:
    """The statistics of N frames (N, H, 2W) the rules read, as arrays.

    Unsigned integer counts (the wire's uint16) are read as they are; anything else is
    cleaned first (NaN as 0, clipped to the counts' range, rounded for the force).
    """
    x = np.asarray(frames)
    if x.ndim != 3 or x.shape[1:] != (FRAME_ROWS, 2 * FRAME_COLS):
        msg = f"frames are (N, {FRAME_ROWS}, {2 * FRAME_COLS}), got {x.shape}"
        raise ValueError(msg)
    n = x.shape[0]
    if x.dtype.kind == "u":
        if n and x.max() > MAX_COUNT:
            x = np.minimum(x, MAX_COUNT)
    else:
        x = np.clip(np.nan_to_num(x.astype(np.float64), nan=0.0), 0.0, MAX_COUNT)
    # (N, foot, H*W): each foot's taxels contiguous, so every sum runs along one axis.
    feet = x.reshape(n, FRAME_ROWS, 2, FRAME_COLS).transpose(0, 2, 1, 3).reshape(n, 2, -1)
    counts = feet if x.dtype.kind == "u" else np.rint(feet).astype(np.intp)
    force = _KPA_OF_COUNT.take(counts).sum(axis=2) * _N_PER_KPA  # (N, 2)
    sums = feet.sum(axis=2, dtype=np.float64)  # (N, 2)
    total = sums.sum(axis=1)
    off = feet.take(_OUTSIDE_TAXELS, axis=2).sum(axis=(1, 2), dtype=np.float64)
    outside = np.where(total > 0, off / np.maximum(total, 1), 0.0)
    if n and x.max() >= RAIL_COUNTS:  # rare: realistic frames stay off the rail
        rail = ((feet >= RAIL_COUNTS) & _MASK_FLAT).sum(axis=2) / _OUTLINE_TAXELS
    else:
        rail = np.zeros((n, 2))
    peak = np.where(sums > 0, feet.max(axis=2, initial=0) / np.maximum(sums, 1), 0.0)
    return FrameStats(force, outside, rail.max(axis=1, initial=0.0), peak.max(axis=1))


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
    checks = list(checks)
    newest = checks[-UNLOADED_FRAMES:]
    unloaded = len(newest) == UNLOADED_FRAMES and not any(c.loaded for c in newest)
    bits = [c.rule_bits for c in checks]
    rules = 0
    if sum(1 for b in bits if b) >= OUT_OF_RANGE_FRAMES:
        for b in bits:
            rules |= b
    full = len(checks) >= window and not unloaded
    left = full and all(c.force_n[0] < FOOT_EMPTY_N for c in checks)
    right = full and all(c.force_n[1] < FOOT_EMPTY_N for c in checks)
    return _verdict_of(unloaded, rules, left, right)


@functools.lru_cache(maxsize=256)
def _verdict_of(unloaded: bool, rules: int, left_empty: bool, right_empty: bool) -> WindowVerdict:
    """The flags and reason lines for what the rules found (few cases: made once each).

    ``rules``: bits of the rules broken somewhere in a window that holds enough
    implausible frames; ``left_empty``/``right_empty``: that foot was empty on every
    frame of a full window that is not unloaded."""
    flags, reasons = [], []
    if unloaded:
        flags.append(UNLOADED)
        reasons.append(
            f"unloaded: both insoles under {UNLOADED_FORCE_N:.0f} N "
            f"for {UNLOADED_FRAMES / FRAME_RATE_HZ:g} s (nobody on them?)"
        )
    what = sorted(_rule_names(rules))
    for foot, empty in (("left", left_empty), ("right", right_empty)):
        if empty:
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
    was a sixth of the inference thread's time (py-spy, 16 pairs). What the rules
    need is kept up to date as frames come and go instead (per frame: its rule
    bits and which feet are empty; per window: counts of those and the newest run
    of unloaded frames), so every frame's verdict costs O(1): the same verdicts as
    ``verdict`` over the window, flag for flag and reason for reason.
    """

    def __init__(self, size: int) -> None:
        if size < 1:
            msg = f"a window of checks needs size >= 1, got {size}"
            raise ValueError(msg)
        self._size = size
        self._codes: deque[tuple[int, bool, bool]] = deque()  # (rule bits, left, right empty)
        self._bad_count = 0  # frames that break any rule
        self._rule_count = [0] * len(RULES)  # frames that break each rule
        self._empty_count = [0, 0]  # frames with the left, the right foot under FOOT_EMPTY_N
        self._unloaded_run = 0  # newest frames in a row that are not loaded

    def push(self, counts: npt.ArrayLike) -> WindowVerdict:
        return self.push_check(check_frame(counts))

    def push_check(self, check: FrameCheck) -> WindowVerdict:
        """Take a frame's check made elsewhere (``check_frames`` of a batch of frames)."""
        left, right = check.force_n
        return self.push_code(
            check.rule_bits, check.loaded, left < FOOT_EMPTY_N, right < FOOT_EMPTY_N
        )

    def push_code(
        self, rule_bits: int, loaded: bool, left_empty: bool, right_empty: bool
    ) -> WindowVerdict:
        """Take a frame as ``FrameStats.codes`` gives it (a batch's frames checked at once)."""
        codes, empty = self._codes, self._empty_count
        if len(codes) == self._size:
            old_bits, old_left, old_right = codes.popleft()
            if old_bits:
                self._count_rules(old_bits, -1)
            empty[0] -= old_left
            empty[1] -= old_right
        codes.append((rule_bits, left_empty, right_empty))
        if rule_bits:
            self._count_rules(rule_bits, 1)
        empty[0] += left_empty
        empty[1] += right_empty
        self._unloaded_run = 0 if loaded else self._unloaded_run + 1
        held = len(codes)
        unloaded = self._unloaded_run >= UNLOADED_FRAMES and held >= UNLOADED_FRAMES
        rules = 0
        if self._bad_count >= OUT_OF_RANGE_FRAMES:
            rules = sum(1 << k for k, n in enumerate(self._rule_count) if n)
        full = held == self._size and not unloaded
        left = full and empty[0] == held
        right = full and empty[1] == held
        if unloaded or rules or left or right:
            return _verdict_of(unloaded, rules, left, right)
        return _CLEAR

    def _count_rules(self, bits: int, step: int) -> None:
        self._bad_count += step
        for k in _RULES_IN[bits]:
            self._rule_count[k] += step

    def reset(self) -> None:
        self._codes.clear()
        self._bad_count = 0
        self._rule_count = [0] * len(RULES)
        self._empty_count = [0, 0]
        self._unloaded_run = 0
