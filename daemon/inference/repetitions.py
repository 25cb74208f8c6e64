"""Repetitions counted from the progress stream.

Progress runs 0 -> 1 through one repetition and falls back to 0 when the
next begins. A fall from above ``high`` to below ``low`` while the action
stays the same counts one repetition; the gap between the two thresholds
keeps noise around one value from counting twice. The action itself must
hold for ``confirm_frames`` predictions before the count starts over, so
one misclassified frame does not reset it.

An action without repetitions (``standing``) counts nothing: while it holds,
the count is -1 (none) and progress is not looked at. A flicker to standing
shorter than ``confirm_frames`` (the top of a squat can look like standing)
neither counts nor resets.

A set goes on through a pause: the labelling convention (models/contract.py)
calls a pause between repetitions longer than ``SET_EDGE_REST_S`` standing, so
a set with long pauses reads squat, standing, squat, ... When the action that
ends a standing of at most ``resume_frames`` predictions is the one before it,
its count goes on from where it stood; after a longer standing, or another
action, the count starts from 0.
"""

from __future__ import annotations

import math

from scotti.models.contract import has_progress


class RepetitionCounter:
    """``update(action, progress) -> repetitions completed in the current action``."""

    # ``high`` 0.55, not nearer 1: a repetition's label is cut as the person arrives at
    # the rest (within 8 % of it, models/progress.py), so it peaks near 0.9, and a model
    # unsure of that moment turns down before it (step-ups topped out near 0.6; at 0.7
    # the shipped model counted 8 of 62 step-ups and 1 of 454 backward steps of a
    # held-out subject). Chosen on the validation subjects 011 and 031 among 0.5-0.7.
    #
    # ``resume_frames`` 128 (8 s at 16 Hz): longer than any pause the simulator draws
    # (sim/actions/strength.py: at most 4.5 s) with room for a person's own, shorter
    # than the stand between two sets of a lab session (stands of 5-20 s and a walk).
    def __init__(
        self,
        high: float = 0.55,
        low: float = 0.3,
        confirm_frames: int = 4,
        resume_frames: int = 128,
    ) -> None:
        if not 0.0 <= low < high <= 1.0:
            msg = f"need 0 <= low < high <= 1, got low={low} high={high}"
            raise ValueError(msg)
        self.high = high
        self.low = low
        self.confirm_frames = confirm_frames
        self.resume_frames = resume_frames
        self.reset()

    def reset(self) -> None:
        self._action: int | None = None
        self._count = 0
        self._armed = False  # progress has been above ``high`` since the last count
        self._candidate: int | None = None
        self._candidate_frames = 0
        # The repeated action a standing interrupted, its count and armed state, and
        # how many predictions the standing has lasted: a pause the set may resume from.
        self._paused: tuple[int, int, bool] | None = None
        self._standing_frames = 0

    @property
    def action(self) -> int | None:
        """The action being counted (after hysteresis)."""
        return self._action

    def update(self, action: int, progress: float) -> int:
        """Repetitions completed in the current action, -1 while it has none (standing)."""
        count = self._update(action, progress)
        return count if self._action is None or has_progress(self._action) else -1

    def _update(self, action: int, progress: float) -> int:
        if action != self._action:
            if action == self._candidate:
                self._candidate_frames += 1
            else:
                self._candidate, self._candidate_frames = action, 1
            if self._action is None or self._candidate_frames >= self.confirm_frames:
                self._switch(action)
            else:
                return self._count  # a flicker: neither counted nor reset
        else:
            self._candidate = None
            if not has_progress(action):
                self._standing_frames += 1
        if not has_progress(action) or math.isnan(progress):
            return self._count
        if progress >= self.high:
            self._armed = True
        elif self._armed and progress <= self.low:
            self._count += 1
            self._armed = False
        return self._count

    def _switch(self, action: int) -> None:
        """The confirmed change to ``action``: a new count, or the paused set's again."""
        left, count, armed = self._action, self._count, self._armed
        paused, standing_frames = self._paused, self._standing_frames
        self._action, self._count, self._armed = action, 0, False
        self._candidate, self._paused = None, None
        if not has_progress(action):
            if left is not None and has_progress(left):
                self._paused = (left, count, armed)  # the set this standing pauses
            # The predictions spent confirming the standing were standing already.
            self._standing_frames = self.confirm_frames
        elif paused is not None and paused[0] == action and standing_frames <= self.resume_frames:
            _, self._count, self._armed = paused
