"""The input checks of a streaming window: what the rules need of its last T frames.

``input_checks.verdict`` walks every frame's check of a window; run per frame
and per device that was a sixth of the inference thread's time (py-spy, 16
pairs). ``FrameChecks`` keeps counts up to date as frames come and go instead,
so each frame's verdict costs O(1), flag for flag and reason for reason the
same as ``verdict`` over the window (tests/test_models_input_checks.py).
"""

from __future__ import annotations

from collections import deque
from typing import Final

import numpy.typing as npt
from scotti.models.input_checks import (
    FOOT_EMPTY_N,
    OUT_OF_RANGE_FRAMES,
    RULES,
    UNLOADED_FRAMES,
    FrameCheck,
    WindowVerdict,
    check_frame,
    verdict_of,
)

_CLEAR: Final = WindowVerdict((), ())
# For each value of the rule bits, the rules it sets (a frame's, counted in and out).
_RULES_IN: Final = tuple(
    tuple(k for k in range(len(RULES)) if bits >> k & 1) for bits in range(1 << len(RULES))
)


class FrameChecks:
    """The checks of the last ``size`` frames, for a streaming window: per frame its
    rule bits and which feet are empty; per window counts of those and the newest run
    of unloaded frames."""

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
            return verdict_of(unloaded, rules, left, right)
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
