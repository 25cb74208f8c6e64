"""The streaming window's input checks: kept counts give the verdicts of the rules run
over the whole window (``verdict``), flag for flag and reason for reason; the wire's
uint16 counts give the statistics their float copies give."""

from __future__ import annotations

import numpy as np
import pytest
from scotti.models.contract import FRAME_COLS, FRAME_ROWS, MAX_COUNT, WINDOW
from scotti.models.input_checks import (
    FOOT_EMPTY_N,
    OUT_OF_RANGE,
    RULES,
    UNLOADED,
    FrameCheck,
    FrameChecks,
    check_frames,
    frame_stats,
    verdict,
)
from scotti.models.insole import insole_mask


def _random_checks(rng: np.random.Generator, n: int) -> list[FrameCheck]:
    """Runs of ordinary, unloaded, one-foot-empty and implausible frames, mixed."""
    out: list[FrameCheck] = []
    while len(out) < n:
        kind = rng.integers(0, 4)
        for _ in range(int(rng.integers(1, 30))):
            left, right = rng.uniform(200, 600, 2)
            if kind == 1:  # nobody there
                left, right = rng.uniform(0, 40, 2)
            elif kind == 2:  # the left insole silent
                left = rng.uniform(0, FOOT_EMPTY_N * 0.9)
            bad = kind == 3 and rng.random() < 0.5
            out.append(FrameCheck((left, right), 0.5 if bad else 0.0, 0.0, 0.1))
    return out[:n]


@pytest.mark.parametrize("size", [40, 8])
def test_kept_counts_give_the_verdict_of_the_whole_window(size: int) -> None:
    rng = np.random.default_rng(size)
    checks = _random_checks(rng, 3000)
    kept = FrameChecks(size)
    flagged = set()
    for i, check in enumerate(checks):
        if i == 1500:
            kept.reset()
        start = 1500 if i >= 1500 else 0
        want = verdict(checks[max(start, i - size + 1) : i + 1], size)
        got = kept.push_check(check)
        assert got == want, i
        flagged.update(got.flags)
    # The draws did reach every rule (else the comparison above proves little).
    assert flagged == ({UNLOADED, OUT_OF_RANGE} if size >= 16 else {OUT_OF_RANGE})


def _mixed_frames(rng: np.random.Generator, n: int) -> np.ndarray:
    """uint16 frames (N, H, 2W) that reach every statistic: light and heavy loads inside
    the outline, load outside it, the rail, one hot taxel, empty frames and feet."""
    mask = np.concatenate([insole_mask(), insole_mask()], axis=1)
    x = rng.gamma(0.8, 400.0, (n, FRAME_ROWS, 2 * FRAME_COLS)) * mask
    x[n // 5 : n // 4] = rng.integers(0, MAX_COUNT // 3, (n // 4 - n // 5, *x.shape[1:]))
    x[n // 4 : n // 3] = np.where(mask, MAX_COUNT, 0)  # at the rail
    x[n // 3 : n // 3 + 3] = 0  # nobody there
    x[n // 2 : n // 2 + 4, :, FRAME_COLS:] = 0  # the right foot empty
    x[n // 2 + 5, 10, 5] = MAX_COUNT * 4  # above the counts' range: read as MAX_COUNT
    x[n // 2 + 6] = 0
    x[n // 2 + 6, 10, 5] = 3000  # one hot taxel
    return np.asarray(np.minimum(x, np.iinfo(np.uint16).max), dtype=np.uint16)


def test_counts_as_uint16_give_the_statistics_of_the_same_counts_as_floats() -> None:
    counts = _mixed_frames(np.random.default_rng(1), 200)
    ints, floats = frame_stats(counts), frame_stats(counts.astype(np.float32))
    np.testing.assert_allclose(ints.force_n, floats.force_n, rtol=1e-12)
    for name in ("outside_share", "rail_share", "peak_share"):
        np.testing.assert_array_equal(getattr(ints, name), getattr(floats, name))
    assert ints.implausible.any()
    assert not ints.implausible.all()
    assert (ints.rail_share > 0).any()
    assert (~ints.loaded).any()


def test_frame_codes_give_the_verdicts_of_frame_checks() -> None:
    """What the streaming window pushes per frame (``FrameStats.codes``) leads to the
    same verdicts as each frame's ``FrameCheck``, and each code is that check's."""
    counts = _mixed_frames(np.random.default_rng(2), 400)
    checks = check_frames(counts)
    bits, loaded, left, right = frame_stats(counts).codes()
    assert bits == [c.rule_bits for c in checks]
    assert [RULES[k] for k in range(len(RULES)) if any(b >> k & 1 for b in bits)] == list(RULES)
    by_check, by_code = FrameChecks(WINDOW), FrameChecks(WINDOW)
    seen = set()
    for i, check in enumerate(checks):
        want = by_check.push_check(check)
        assert by_code.push_code(bits[i], loaded[i], left[i], right[i]) == want, i
        assert want == verdict(checks[max(0, i - WINDOW + 1) : i + 1], WINDOW), i
        seen.update(want.reasons)
    assert len(seen) >= 3  # unloaded, a foot empty, out of the outline / at the rail
