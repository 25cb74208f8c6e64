"""The streaming window's input checks: kept counts give the verdicts of the rules run
over the whole window (``verdict``), flag for flag and reason for reason."""

from __future__ import annotations

import numpy as np
import pytest
from scotti.models.contract import WINDOW
from scotti.models.input_checks import (
    FOOT_EMPTY_N,
    OUT_OF_RANGE,
    RULES,
    UNLOADED,
    FrameCheck,
    check_frames,
    frame_codes,
    verdict,
)
from scotti.models.window_checks import FrameChecks

from tests.test_models_input_checks import mixed_frames


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


def test_frame_codes_give_the_verdicts_of_frame_checks() -> None:
    """What the streaming window pushes per frame (``frame_codes``) leads to the
    same verdicts as each frame's ``FrameCheck``, and each code is that check's."""
    counts = mixed_frames(np.random.default_rng(2), 400)
    checks = check_frames(counts)
    codes = frame_codes(counts)
    assert codes == [
        (c.rule_bits, c.loaded, c.force_n[0] < FOOT_EMPTY_N, c.force_n[1] < FOOT_EMPTY_N)
        for c in checks
    ]
    bits = [code[0] for code in codes]
    assert [RULES[k] for k in range(len(RULES)) if any(b >> k & 1 for b in bits)] == list(RULES)
    by_check, by_code = FrameChecks(WINDOW), FrameChecks(WINDOW)
    seen = set()
    for i, check in enumerate(checks):
        want = by_check.push_check(check)
        assert by_code.push_code(*codes[i]) == want, i
        assert want == verdict(checks[max(0, i - WINDOW + 1) : i + 1], WINDOW), i
        seen.update(want.reasons)
    assert len(seen) >= 3  # unloaded, a foot empty, out of the outline / at the rail
