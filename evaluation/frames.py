"""Predictions and labels of evaluated frames, aligned by row (``FrameSet``), and
what pooled scoring keeps of them (``FrameScores``).

A prediction made from the frames t-T..t-1 is for time t: ``align`` matches
each prediction to the label record of that time by unwrapped sequence
number.

Why two: a ``FrameSet`` holds both poses, about 500 bytes a frame; pooling a
few held-out subjects' sessions that way (and the copies concatenation and
per-action subsets make) took ``scotti eval`` to 1.6 GB. Every pooled figure
needs only each frame's pose errors, so ``FrameScores`` keeps those: 48 bytes
a frame, the same figures.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scotti.evaluation.sampling import Prediction
from scotti.firmware_protocol.session import LabelRecord
from scotti.firmware_protocol.wrap import seq_delta
from scotti.models import metrics
from scotti.models.contract import NUM_KEYPOINTS, has_progress

F32 = npt.NDArray[np.float32]
I64 = npt.NDArray[np.int64]


@dataclass
class FrameSet:
    """Predictions and labels of N evaluated frames, aligned by row."""

    pose_pred: F32  # (N, 19, 3) metres
    pose_true: F32  # (N, 19, 3) metres, NaN where unknown
    action_pred: I64  # (N,) argmax of the action probabilities
    action_true: I64  # (N,) NO_ACTION where the label names none (a transition)
    progress_pred: npt.NDArray[np.float64]  # (N,) the progress head's output, as it is
    progress_true: npt.NDArray[np.float64]  # (N,) NaN where undefined (standing, transition)

    @classmethod
    def empty(cls) -> FrameSet:
        return cls(
            np.zeros((0, NUM_KEYPOINTS, 3), np.float32),
            np.zeros((0, NUM_KEYPOINTS, 3), np.float32),
            np.zeros(0, np.int64),
            np.zeros(0, np.int64),
            np.zeros(0),
            np.zeros(0),
        )

    @classmethod
    def concat(cls, parts: Sequence[FrameSet]) -> FrameSet:
        if not parts:
            return cls.empty()
        return cls(
            *(
                np.concatenate([getattr(p, name) for p in parts])
                for name in (
                    "pose_pred",
                    "pose_true",
                    "action_pred",
                    "action_true",
                    "progress_pred",
                    "progress_true",
                )
            )
        )

    @classmethod
    def from_labels(cls, labels: Sequence[LabelRecord]) -> FrameSet:
        """The labels predicted perfectly: the metric path's sanity check."""
        pose = np.zeros((len(labels), NUM_KEYPOINTS, 3), dtype=np.float32)
        for i, lb in enumerate(labels):
            pose[i] = lb.keypoints
        action = np.array([lb.action for lb in labels], dtype=np.int64)
        progress = progress_true(labels)
        return cls(pose, pose, action, action, np.nan_to_num(progress), progress)

    def __len__(self) -> int:
        return int(self.action_true.shape[0])

    def subset(self, keep: npt.NDArray[np.bool_]) -> FrameSet:
        return FrameSet(
            self.pose_pred[keep],
            self.pose_true[keep],
            self.action_pred[keep],
            self.action_true[keep],
            self.progress_pred[keep],
            self.progress_true[keep],
        )


@dataclass
class FrameScores:
    """Per-frame figures of N evaluated frames, aligned by row: all that pooled scoring
    needs (``evaluation.scores``), without the poses."""

    position_error_m: npt.NDArray[np.float64]  # (N,) mean keypoint distance, NaN: no keypoint
    angle_error_deg: npt.NDArray[np.float64]  # (N,) mean joint angle error, NaN: no angle
    action_pred: I64
    action_true: I64
    progress_pred: npt.NDArray[np.float64]
    progress_true: npt.NDArray[np.float64]

    _FIELDS = (
        "position_error_m",
        "angle_error_deg",
        "action_pred",
        "action_true",
        "progress_pred",
        "progress_true",
    )

    @classmethod
    def of(cls, frames: FrameSet) -> FrameScores:
        if not len(frames):
            return cls.empty()
        return cls(
            metrics.position_error_m(frames.pose_pred, frames.pose_true),
            metrics.angle_error_deg(frames.pose_pred, frames.pose_true),
            frames.action_pred,
            frames.action_true,
            frames.progress_pred,
            frames.progress_true,
        )

    @classmethod
    def empty(cls) -> FrameScores:
        none = np.zeros(0)
        return cls(none, none, np.zeros(0, np.int64), np.zeros(0, np.int64), none, none)

    @classmethod
    def concat(cls, parts: Sequence[FrameScores]) -> FrameScores:
        if not parts:
            return cls.empty()
        return cls(*(np.concatenate([getattr(p, name) for p in parts]) for name in cls._FIELDS))

    def __len__(self) -> int:
        return int(self.action_true.shape[0])

    def subset(self, keep: npt.NDArray[np.bool_]) -> FrameScores:
        return FrameScores(*(getattr(self, name)[keep] for name in self._FIELDS))


def align(made: list[Prediction], labels: list[LabelRecord]) -> tuple[FrameSet, int]:
    """Match predictions to labels by unwrapped seq; returns the frames and the misses."""
    if not made or not labels:
        return FrameSet.empty(), len(made)
    # Labels come in seq order; unwrap them onto the pairs' axis from the first pair's seq.
    first = made[0].ext - 1  # any pair's ext anchors the two axes
    index: dict[int, int] = {}
    ext = first + seq_delta(labels[0].seq, first & 0xFFFF)
    prev = labels[0].seq
    for i, label in enumerate(labels):
        ext += seq_delta(label.seq, prev)
        prev = label.seq
        index[ext] = i
    rows = [(m, index.get(m.ext)) for m in made]
    hits = [(m, i) for m, i in rows if i is not None]
    if not hits:
        return FrameSet.empty(), len(made)
    chosen = [labels[i] for _, i in hits]
    truth = FrameSet.from_labels(chosen)
    frames = FrameSet(
        pose_pred=np.stack([m.pose for m, _ in hits]).astype(np.float32),
        pose_true=truth.pose_true,
        action_pred=np.array([int(np.argmax(m.probs)) for m, _ in hits], dtype=np.int64),
        action_true=truth.action_true,
        progress_pred=np.array([m.progress for m, _ in hits], dtype=np.float64),
        progress_true=truth.progress_true,
    )
    return frames, len(made) - len(hits)


def progress_true(labels: Sequence[LabelRecord]) -> npt.NDArray[np.float64]:
    """Progress counts only where it is defined: a repeated action (as in training's loss)."""
    return np.array(
        [lb.progress if has_progress(lb.action) else np.nan for lb in labels], dtype=np.float64
    )
