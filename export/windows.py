"""Windows over decoded sessions, chunks of consecutive windows, subject-wise splits.

A window starting at slot i holds frames i .. i+T-1 and is labelled with
slot i+T: frames t-T..t-1 predict time t, one frame ahead, as in the paper.

Training takes windows in chunks: K windows whose starts are ``stride``
slots apart need only (K-1)*stride + T frames, so each frame goes through
the CNN once per chunk instead of once per window (export/TRAINING.md).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scotti.export import tempo as tempo_mod
from scotti.export.data import SessionArrays, TrainingDataError
from scotti.models import contract


@dataclass(frozen=True)
class Chunk:
    """``count`` windows of one session, starting at ``start``, ``stride`` slots apart."""

    session: int
    start: int
    count: int
    stride: int
    window: int

    @property
    def frame_count(self) -> int:
        """Frames that the chunk's windows cover together."""
        return (self.count - 1) * self.stride + self.window

    @property
    def target_slots(self) -> np.ndarray:
        return self.start + self.window + self.stride * np.arange(self.count)


@dataclass(frozen=True)
class Targets:
    keypoints: np.ndarray  # (K, 19, 3) float32
    action: np.ndarray  # (K,) int64, NO_ACTION for a transition
    progress: np.ndarray  # (K,) float32, NaN where undefined (standing, transition)


class WindowDataset:
    """All usable windows of a set of sessions (see ``usable_starts``)."""

    def __init__(
        self,
        sessions: Sequence[SessionArrays],
        window: int = contract.WINDOW,
        *,
        allow_invalid: bool = False,
    ) -> None:
        self.sessions = list(sessions)
        self.window = window
        self.allow_invalid = allow_invalid
        self._usable = [self.usable_starts(s) for s in self.sessions]

    def usable_starts(self, s: SessionArrays) -> np.ndarray:
        """(max(N-T, 0),) bool: the window at this start is usable.

        Its target slot has a label, it stays in one segment, and (unless
        ``allow_invalid``) no input frame has a zero-filled foot (``frame_ok``).
        """
        t, n = self.window, len(s)
        if n <= t:
            return np.zeros(0, dtype=bool)
        ok: np.ndarray = s.has_label[t:] & (s.segment[:-t] == s.segment[t:])
        if not self.allow_invalid:
            bad = np.concatenate([[0], np.cumsum(~s.frame_ok)])  # bad[i] = invalid in [0, i)
            ok &= (bad[t:n] - bad[: n - t]) == 0
        return ok

    def __len__(self) -> int:
        return self.count(stride=1)

    def target_counts(self) -> dict[str, int]:
        """Usable windows (stride 1) per target action by name, "transition" for NO_ACTION.

        Training draws windows uniformly (no class balancing), so these are
        the weights the actions get in the action loss.
        """
        names = (*contract.ACTIONS, "transition")  # index -1 picks the last
        counts = dict.fromkeys(names, 0)
        for i, s in enumerate(self.sessions):
            targets = s.action[self.starts(i) + self.window]
            for action, n in zip(*np.unique(targets, return_counts=True), strict=True):
                counts[names[int(action)]] += int(n)
        return counts

    def count(self, stride: int = 1, phase: int = 0) -> int:
        return sum(int(u[phase::stride].sum()) for u in self._usable)

    def starts(self, session: int, stride: int = 1, phase: int = 0) -> np.ndarray:
        """Usable window starts of one session on the grid phase, phase+stride, ..."""
        idx = np.arange(phase, self._usable[session].size, stride)
        keep: np.ndarray = idx[self._usable[session][idx]]
        return keep

    def chunks(
        self,
        *,
        stride: int,
        chunk: int,
        phase: int = 0,
        rng: np.random.Generator | None = None,
    ) -> list[Chunk]:
        """Runs of consecutive usable windows (``stride`` apart), cut into pieces of <= chunk.

        With ``rng`` the first piece of every run gets a random length, so
        chunk boundaries move from epoch to epoch.
        """
        if stride < 1 or chunk < 1:
            msg = f"stride and chunk must be >= 1, got {stride} and {chunk}"
            raise TrainingDataError(msg)
        out: list[Chunk] = []
        for si in range(len(self.sessions)):
            starts = self.starts(si, stride, phase)
            if starts.size == 0:
                continue
            run_breaks = np.flatnonzero(np.diff(starts) != stride) + 1
            for run in np.split(starts, run_breaks):
                pos = 0
                if rng is not None and run.size > chunk:
                    pos = int(rng.integers(0, chunk))
                    if pos:
                        out.append(Chunk(si, int(run[0]), pos, stride, self.window))
                while pos < run.size:
                    k = min(chunk, run.size - pos)
                    out.append(Chunk(si, int(run[pos]), k, stride, self.window))
                    pos += k
        return out

    def frames(self, c: Chunk, tempo: float = 1.0) -> np.ndarray:
        """(chunk.frame_count, H, 2W), the frames the chunk's windows share: uint16 as
        decoded, or float32 read between slots at another ``tempo`` (export/tempo.py)."""
        s = self.sessions[c.session]
        if tempo == 1.0:
            return s.frames[c.start : c.start + c.frame_count]
        return tempo_mod.read_between(s.frames, self._positions(c, tempo)[0])

    def targets(self, c: Chunk, tempo: float = 1.0) -> Targets:
        s = self.sessions[c.session]
        if tempo == 1.0:
            slots = c.target_slots
            return Targets(s.keypoints[slots], s.action[slots], s.progress[slots])
        pos = self._positions(c, tempo)[1]
        return Targets(
            tempo_mod.read_between(s.keypoints, pos),
            tempo_mod.nearest(s.action, pos),
            tempo_mod.nearest(s.progress, pos),
        )

    def fits_tempo(self, c: Chunk, tempo: float) -> bool:
        """The chunk may be played at ``tempo`` (export/tempo.py's ``fits``)."""
        return tempo == 1.0 or tempo_mod.fits(self.sessions[c.session], *self._positions(c, tempo))

    @staticmethod
    def _positions(c: Chunk, tempo: float) -> tuple[np.ndarray, np.ndarray]:
        return tempo_mod.positions(c.start, c.frame_count, c.window, c.stride, c.count, tempo)

    def window_at(self, session: int, start: int) -> tuple[np.ndarray, Targets]:
        """One window the naive way: (T, H, 2W) frames and its one-frame-ahead target."""
        c = Chunk(session, start, 1, 1, self.window)
        return self.frames(c), self.targets(c)


@dataclass(frozen=True)
class Split:
    train: list[SessionArrays]
    test: list[SessionArrays]
    train_subjects: list[str]
    test_subjects: list[str]
    kind: str  # "subject": whole subjects held out; "time": each session's tail; "none"

    def describe(self) -> dict[str, Any]:
        """What the checkpoint and the model card record about the split."""
        return {
            "kind": self.kind,
            "train_subjects": self.train_subjects,
            "test_subjects": self.test_subjects,
            "train_files": sorted({s.path for s in self.train}),
            "test_files": sorted({s.path for s in self.test}),
        }


def split_by_subject(
    sessions: Sequence[SessionArrays],
    test_subjects: Sequence[str] | None = None,
    *,
    test_fraction: float = 0.2,
    seed: int = 0,
) -> Split:
    """Hold out whole subjects: those named, else a seeded ``test_fraction`` of them.

    With a single subject and nothing named there is nobody to hold out; the
    last ``test_fraction`` of every session is held out instead ("time").
    """
    subjects = sorted({s.subject for s in sessions})
    if test_subjects:
        unknown = sorted(set(test_subjects) - set(subjects))
        if unknown:
            msg = f"unknown test subject(s) {', '.join(unknown)}; have {', '.join(subjects)}"
            raise TrainingDataError(msg)
        held = sorted(set(test_subjects))
    elif len(subjects) >= 2 and test_fraction > 0:
        n_test = min(len(subjects) - 1, max(1, round(test_fraction * len(subjects))))
        order = np.random.default_rng(seed).permutation(len(subjects))
        held = sorted(subjects[i] for i in order[:n_test])
    elif test_fraction > 0:
        train, test = [], []
        for s in sessions:
            cut = round(len(s) * (1.0 - test_fraction))
            train.append(s.slice(0, cut))
            test.append(s.slice(cut, len(s)))
        return Split(train, test, subjects, subjects, "time")
    else:
        return Split(list(sessions), [], subjects, [], "none")
    train = [s for s in sessions if s.subject not in held]
    test = [s for s in sessions if s.subject in held]
    if not train:
        msg = "every subject is a test subject: nothing left to train on"
        raise TrainingDataError(msg)
    return Split(train, test, sorted(set(subjects) - set(held)), held, "subject")
