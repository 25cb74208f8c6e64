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

Per-frame statistics are computed once per frame (``FrameCheck``, or
``frame_codes`` for a batch) so the streaming window keeps what the rules need
of the last T frames instead of the frames (models/window_checks.py). Numpy
only (ARCHITECTURE.md, room ``models/``).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Final

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


_MASK_FLAT: Final = _MASK.ravel()  # one foot's taxels, row by row
_OUTSIDE_TAXELS: Final = np.flatnonzero(~_MASK_FLAT)
_OUTLINE_TAXELS: Final = int(_MASK.sum())
# (H*W, 2): a foot's taxels -> (all counts, counts outside the outline).
_SUM_AND_OUTSIDE: Final = np.stack([np.ones(_MASK.size), ~_MASK_FLAT], axis=1).astype(np.int64)


def frame_stats(frames: npt.ArrayLike) -> FrameStats:
    """The statistics of N frames (N, H, 2W) the rules read, as arrays.

    Unsigned integer counts (the wire's uint16) are read as they are; anything else is
    cleaned first (NaN as 0, clipped to the counts' range, rounded for the force).
    """
    feet, whole = _feet(frames)
    top = feet.max(initial=0)
    if whole and top > MAX_COUNT:
        feet = np.minimum(feet, MAX_COUNT)
    sums_off = _sums_and_outside(feet, whole)
    sums = sums_off[:, :, 0]
    total = sums.sum(axis=1)
    off = sums_off[:, :, 1].sum(axis=1)
    outside = np.where(total > 0, off / np.maximum(total, 1), 0.0)
    peak = np.where(sums > 0, feet.max(axis=2, initial=0) / np.maximum(sums, 1), 0.0)
    rail = _at_rail(feet) / _OUTLINE_TAXELS if top >= RAIL_COUNTS else np.zeros((len(feet), 2))
    force = _kpa_sums(feet, whole) * _N_PER_KPA
    return FrameStats(force, outside, rail.max(axis=1), peak.max(axis=1))


# What ``FrameChecks.push_code`` takes for one frame: rule bits, loaded, left foot
# empty, right foot empty.
FrameCode = tuple[int, bool, bool, bool]


def frame_codes(frames: npt.ArrayLike) -> list[FrameCode]:
    """``FrameCheck.rule_bits``, ``loaded`` and the empty feet of N frames (N, H, 2W).

    ``frame_stats``' figures, the same floats, with the per-frame arithmetic in Python
    on a few sums per foot: in the daemon this runs between two model calls, where
    each numpy call (even on a numpy scalar) costs tens of microseconds of cold caches
    whatever its size, more than the Python that replaces it for a batch of a few frames.
    """
    feet, whole = _feet(frames)
    peaks = feet.max(axis=2, initial=0).tolist()
    top = max((max(p) for p in peaks), default=0)
    if whole and top > MAX_COUNT:
        feet = np.minimum(feet, MAX_COUNT)
        peaks = feet.max(axis=2, initial=0).tolist()
    rails = _at_rail(feet).tolist() if top >= RAIL_COUNTS else [(0, 0)] * len(peaks)
    codes = []
    for (k_left, k_right), ((s_left, o_left), (s_right, o_right)), (p_left, p_right), r in zip(
        _kpa_sums(feet, whole).tolist(),
        _sums_and_outside(feet, whole).tolist(),
        peaks,
        rails,
        strict=True,
    ):
        f_left, f_right = k_left * _N_PER_KPA, k_right * _N_PER_KPA
        force_n = f_left + f_right
        total = s_left + s_right
        outside = (o_left + o_right) / max(total, 1) if total > 0 else 0.0
        peak_share = max(
            p_left / max(s_left, 1) if s_left > 0 else 0.0,
            p_right / max(s_right, 1) if s_right > 0 else 0.0,
        )
        bits = (
            (outside > OUTSIDE_SHARE_MAX)
            | (max(r) / _OUTLINE_TAXELS > RAIL_SHARE_MAX) << 1
            | (peak_share > PEAK_SHARE_MAX) << 2
            | (force_n > FORCE_MAX_N) << 3
        )
        codes.append(
            (bits, force_n >= UNLOADED_FORCE_N, f_left < FOOT_EMPTY_N, f_right < FOOT_EMPTY_N)
        )
    return codes


def _feet(frames: npt.ArrayLike) -> tuple[npt.NDArray[Any], bool]:
    """(N, foot, H*W), each foot's taxels contiguous so that every sum runs along one
    axis; and whether they are whole counts (unsigned integers, read as they are: the
    wire's uint16) or were cleaned (NaN as 0, clipped to the counts' range, float64)."""
    x = np.asarray(frames)
    if x.ndim != 3 or x.shape[1:] != (FRAME_ROWS, 2 * FRAME_COLS):
        msg = f"frames are (N, {FRAME_ROWS}, {2 * FRAME_COLS}), got {x.shape}"
        raise ValueError(msg)
    whole = x.dtype.kind == "u"
    if not whole:
        x = np.clip(np.nan_to_num(x.astype(np.float64), nan=0.0), 0.0, MAX_COUNT)
    n = x.shape[0]
    return x.reshape(n, FRAME_ROWS, 2, FRAME_COLS).transpose(0, 2, 1, 3).reshape(n, 2, -1), whole


def _kpa_sums(feet: npt.NDArray[Any], whole: bool) -> npt.NDArray[np.float64]:
    """(N, 2): each foot's taxels in kPa, summed (the counts rounded to whole ones)."""
    return np.asarray(
        _KPA_OF_COUNT.take(feet if whole else np.rint(feet).astype(np.intp)).sum(axis=2)
    )


def _sums_and_outside(feet: npt.NDArray[Any], whole: bool) -> npt.NDArray[Any]:
    """(N, foot, 2): each foot's counts and those outside the outline, summed."""
    if whole:  # integer products: numpy's own loop (no BLAS threads), exact, one call
        return np.asarray(feet @ _SUM_AND_OUTSIDE)
    outside = feet.take(_OUTSIDE_TAXELS, axis=2).sum(axis=2)
    return np.stack([feet.sum(axis=2), outside], axis=2)


def _at_rail(feet: npt.NDArray[Any]) -> npt.NDArray[np.int64]:
    """(N, 2): each foot's outline taxels at the rail."""
    return np.asarray(((feet >= RAIL_COUNTS) & _MASK_FLAT).sum(axis=2, dtype=np.int64))


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
    return verdict_of(unloaded, rules, left, right)


@functools.lru_cache(maxsize=256)
def verdict_of(unloaded: bool, rules: int, left_empty: bool, right_empty: bool) -> WindowVerdict:
    """The flags and reason lines for what the rules found (few cases: made once each,
    shared by ``verdict`` and the streaming window's kept counts, models/window_checks.py).

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


def __getattr__(name: str) -> Any:
    # FrameChecks lives in window_checks.py (it imports this module); importable from
    # here too, where callers found it before.
    if name == "FrameChecks":
        from scotti.models.window_checks import FrameChecks

        return FrameChecks
    msg = f"module {__name__!r} has no attribute {name!r}"
    raise AttributeError(msg)
