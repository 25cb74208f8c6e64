"""The onnxruntime wrapper the daemon runs: load, check against the contract, infer.

A SCOTTI export is two graphs from one set of weights (ARCHITECTURE.md, model I/O):
``NAME.onnx``, the streaming step (one new frame + the cached embeddings of
the previous T-1 frames -> pose, action logits, progress, the new frame's
embedding), and ``NAME.window.onnx`` (B windows of T frames -> the heads).
``ScottiRuntime`` loads either one and refuses, with a one-line
``ModelContractError``, any file whose metadata or inputs and outputs do not
fit ``contract.py`` (the checks: models/graph_checks.py).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from scotti.models import contract as c
from scotti.models.errors import ModelContractError, ModelError, ModelInputError
from scotti.models.graph_checks import (
    check_io,
    check_metadata,
    ood_stats,
    open_session,
    sha256_of,
)
from scotti.models.ood import UNFAMILIAR, OodStats
from scotti.models.progress_calibration import ProgressCalibration, ProgressMapping

F32 = npt.NDArray[np.float32]


@dataclass(frozen=True)
class StepResult:
    """One streaming step: the prediction for the frame after the window."""

    pose: F32  # (19, 3) metres, pose frame
    action_logits: F32  # (8,)
    action_probs: F32  # (8,) softmax of the logits
    progress: float  # 0..1 through the current repetition
    embedding: F32  # (E,) the new frame's embedding, for the cache
    pooled: F32 | None = None  # (E,) what the heads read; None from a graph without it
    unfamiliar_score: float | None = None  # Mahalanobis distance; None: not calibrated
    flags: tuple[str, ...] = ()  # "unfamiliar"; the streaming window adds the input flags


def _above(
    scores: npt.NDArray[np.float64] | None, threshold: float | None, rows: int
) -> npt.NDArray[np.bool_]:
    """Which of ``rows`` unfamiliar scores exceed the threshold (none when not calibrated)."""
    if scores is None or threshold is None:
        return np.zeros(rows, dtype=bool)
    return np.asarray(scores > threshold)


@dataclass(frozen=True)
class WindowResult:
    """Predictions for B windows (window graph)."""

    pose: F32  # (B, 19, 3)
    action_logits: F32  # (B, NUM_ACTIONS)
    action_probs: F32  # (B, NUM_ACTIONS)
    progress: F32  # (B,)
    pooled: F32 | None = None  # (B, E); None from a graph without it
    unfamiliar_score: npt.NDArray[np.float64] | None = None  # (B,); None: not calibrated
    threshold: float | None = None  # the OOD threshold the scores were judged by

    @property
    def unfamiliar(self) -> npt.NDArray[np.bool_]:
        """(B,) scores above the calibrated threshold (all False when not calibrated)."""
        return _above(self.unfamiliar_score, self.threshold, self.progress.shape[0])


@dataclass(frozen=True)
class StepBatch:
    """B streaming steps from one call (``run_steps``), row i for frame i."""

    pose: F32  # (B, 19, 3)
    action_logits: F32  # (B, NUM_ACTIONS)
    action_probs: F32  # (B, NUM_ACTIONS)
    progress: F32  # (B,)
    embedding: F32  # (B, E)
    pooled: F32 | None = None  # (B, E); None from a graph without it
    unfamiliar_score: npt.NDArray[np.float64] | None = None  # (B,); None: not calibrated
    threshold: float | None = None  # the OOD threshold the scores were judged by

    @property
    def unfamiliar(self) -> npt.NDArray[np.bool_]:
        """(B,) scores above the calibrated threshold (all False when not calibrated)."""
        return _above(self.unfamiliar_score, self.threshold, self.progress.shape[0])

    def row(self, i: int, input_flags: tuple[str, ...] = ()) -> StepResult:
        """Row i as one result; ``input_flags`` (the window's input checks) go before
        the runtime's own ``unfamiliar``."""
        progress, scores, unfamiliar = self._scalars
        return StepResult(
            self.pose[i],
            self.action_logits[i],
            self.action_probs[i],
            progress[i],
            self.embedding[i],
            None if self.pooled is None else self.pooled[i],
            None if scores is None else scores[i],
            (*input_flags, UNFAMILIAR) if unfamiliar[i] else input_flags,
        )

    @functools.cached_property
    def _scalars(self) -> tuple[list[float], list[float] | None, list[bool]]:
        """Progress, score and unfamiliar of every row as Python values, made once for
        all the rows (one conversion per batch, not one per row)."""
        if self.unfamiliar_score is None or self.threshold is None:
            scores = None if self.unfamiliar_score is None else self.unfamiliar_score.tolist()
            return self.progress.tolist(), scores, [False] * len(self.progress)
        scores = self.unfamiliar_score.tolist()
        threshold = self.threshold
        return self.progress.tolist(), scores, [score > threshold for score in scores]


def softmax(logits: npt.ArrayLike, axis: int = -1) -> F32:
    """Softmax that cannot overflow: the largest logit is subtracted first."""
    x = np.asarray(logits, dtype=np.float32)
    e: F32 = np.exp(x - x.max(axis=axis, keepdims=True))
    e /= e.sum(axis=axis, keepdims=True)  # in place: one numpy call fewer per batch
    return e


class ScottiRuntime:
    """One SCOTTI graph (step or window) in an onnxruntime CPU session."""

    def __init__(
        self, path: str | Path, threads: int = 1, *, calibrate_progress: bool = True
    ) -> None:
        """``calibrate_progress`` False: the progress head's output as it is, whatever the
        metadata holds (what ``scotti calibrate`` fits a calibration on)."""
        self._path = Path(path)
        if threads < 1:
            msg = f"threads must be at least 1, got {threads}"
            raise ModelError(msg)
        self._threads = threads
        self._sha256 = sha256_of(self._path)
        self._session = open_session(self._path, threads)
        meta = dict(self._session.get_modelmeta().custom_metadata_map)
        try:
            self._graph, self._window, self._embed_dim, self._card = check_metadata(meta)
            self._has_pooled = check_io(self._session, self._graph, self._window, self._embed_dim)
            self._ood = ood_stats(meta, self._embed_dim, self._has_pooled)
            progress = ProgressMapping.from_metadata(meta, switched_on=calibrate_progress)
        except ModelContractError as exc:
            msg = f"{self._path.name}: {exc}"
            raise ModelContractError(msg) from None
        self._outputs = [c.OUTPUT_POSE, c.OUTPUT_ACTION_LOGITS, c.OUTPUT_PROGRESS]
        if self._graph == "step":
            self._outputs.append(c.STEP_OUTPUT_EMBEDDING)
        if self._has_pooled:
            self._outputs.append(c.OUTPUT_POOLED)
        self._frame_shape = (c.FRAME_ROWS, 2 * c.FRAME_COLS)
        self._progress = progress

    # --- what was loaded -----------------------------------------------------

    @property
    def path(self) -> Path:
        return self._path

    @property
    def sha256(self) -> str:
        """Hex digest of the file as loaded (the daemon reports it in ``info``)."""
        return self._sha256

    @property
    def graph(self) -> str:
        """``"step"`` or ``"window"``."""
        return self._graph

    @property
    def window(self) -> int:
        """T, frames per window."""
        return self._window

    @property
    def embed_dim(self) -> int:
        """E, width of one frame embedding."""
        return self._embed_dim

    @property
    def threads(self) -> int:
        return self._threads

    @property
    def card(self) -> dict[str, Any]:
        """The model card from metadata ``scotti.card`` ({} if the export has none)."""
        return dict(self._card)

    @property
    def ood(self) -> OodStats | None:
        """The training data's pooled-vector statistics (None: not calibrated)."""
        return self._ood

    @property
    def progress_calibration(self) -> ProgressCalibration | None:
        """The map applied to every progress output (None: the head's output as it is)."""
        return self._progress.applied

    def progress_calibration_info(self) -> dict[str, Any]:
        """What ``info`` says about progress: calibrated (and on what) or not."""
        return self._progress.info()

    def ood_info(self) -> dict[str, Any]:
        """What ``info`` says about the unfamiliar score: calibrated or why not."""
        if self._ood is None:
            why = (
                "the graph has no pooled output (an export from before the OOD score)"
                if not self._has_pooled
                else "the model carries no OOD statistics (export it with --calibrate)"
            )
            return {"calibrated": False, "reason": f"not calibrated: {why}"}
        return {
            "calibrated": True,
            "threshold": self._ood.threshold,
            "summary": self._ood.summary,
        }

    @property
    def frame_shape(self) -> tuple[int, int]:
        """(H, 2W): one input frame, left insole then right, raw counts."""
        return self._frame_shape

    # --- inference ---------------------------------------------------------------

    def step(self, frame: npt.ArrayLike, past: npt.ArrayLike) -> StepResult:
        """One new frame (H, 2W) + the previous T-1 embeddings (T-1, E), oldest first."""
        f = _as_f32(frame, self._frame_shape, "frame")
        p = _as_f32(past, (self._window - 1, self._embed_dim), "past embeddings")
        return self.run_steps(f[None], p[None]).row(0)

    def step_batch(self, frames: npt.ArrayLike, past: npt.ArrayLike) -> list[StepResult]:
        """B new frames (B, H, 2W) + each one's previous T-1 embeddings (B, T-1, E) in one
        onnxruntime call (the step graph's batch axis): one result per row, in order.

        Many insole pairs share one model this way: the graph's fixed cost (weights
        walked once, one kernel launch per operator) is paid once per turn, not per pair.
        """
        batch = self.run_steps(frames, past)
        return [batch.row(i) for i in range(len(batch.progress))]

    def run_steps(self, frames: npt.ArrayLike, past: npt.ArrayLike) -> StepBatch:
        """``step_batch`` as arrays, one row per frame (no object per row: the batched
        evaluation replay reads thousands of rows a second)."""
        if self._graph != "step":
            msg = f"{self._path.name} is a window graph; step() needs the step graph"
            raise ModelError(msg)
        f = np.ascontiguousarray(frames, dtype=np.float32)
        p = np.ascontiguousarray(past, dtype=np.float32)
        if f.ndim != 3 or f.shape[1:] != self._frame_shape or len(f) < 1:
            msg = f"frames must be (B, {', '.join(map(str, self._frame_shape))}), got {f.shape}"
            raise ModelInputError(msg)
        want_past = (len(f), self._window - 1, self._embed_dim)
        if p.shape != want_past:
            msg = f"past embeddings must be {want_past}, got {p.shape}"
            raise ModelInputError(msg)
        pose, logits, progress, embedding, *rest = self._session.run(
            self._outputs, {c.STEP_INPUT_FRAME: f, c.STEP_INPUT_PAST: p}
        )
        pooled = rest[0] if rest else None
        ood = self._ood
        score = (
            ood.score(pooled, logits.argmax(axis=-1))
            if pooled is not None and ood is not None
            else None
        )
        threshold = ood.threshold if ood is not None else None
        return StepBatch(
            pose,
            logits,
            softmax(logits),
            self._calibrated(progress, logits),
            embedding,
            pooled,
            score,
            threshold,
        )

    def run_windows(self, frames: npt.ArrayLike, batch_size: int = 32) -> WindowResult:
        """B windows (B, T, H, 2W) of raw counts -> the heads for each; window graph only."""
        if self._graph != "window":
            msg = (
                f"{self._path.name} is a step graph; run_windows() needs the window graph "
                f"{window_graph_for(self._path).name}"
            )
            raise ModelError(msg)
        x = np.asarray(frames, dtype=np.float32)
        expected = (self._window, *self._frame_shape)
        if x.ndim != 4 or x.shape[1:] != expected:
            msg = f"frames must be (B, {', '.join(map(str, expected))}), got {x.shape}"
            raise ModelInputError(msg)
        chunks = [
            self._session.run(self._outputs, {c.WINDOW_INPUT_FRAMES: x[i : i + batch_size]})
            for i in range(0, len(x), max(batch_size, 1))
        ]
        if not chunks:
            logits = np.zeros((0, c.NUM_ACTIONS), np.float32)
            return WindowResult(
                np.zeros((0, c.NUM_KEYPOINTS, 3), np.float32),
                logits,
                logits.copy(),
                np.zeros(0, np.float32),
            )
        pose, logits, progress, *rest = (
            np.concatenate(parts) for parts in zip(*chunks, strict=True)
        )
        pooled = rest[0] if rest else None
        ood = self._ood
        score = (
            ood.score(pooled, logits.argmax(axis=-1))
            if pooled is not None and ood is not None
            else None
        )
        threshold = ood.threshold if ood is not None else None
        progress = self._calibrated(progress, logits)
        return WindowResult(pose, logits, softmax(logits), progress, pooled, score, threshold)

    def _calibrated(self, progress: F32, logits: F32) -> F32:
        return self._progress(progress, logits)

    # --- files -------------------------------------------------------------------

    @staticmethod
    def window_graph_for(step_path: str | Path) -> Path:
        """NAME.onnx -> NAME.window.onnx (and NAME.int8.onnx -> NAME.int8.window.onnx)."""
        return window_graph_for(step_path)

    def __repr__(self) -> str:
        return f"ScottiRuntime({str(self._path)!r}, graph={self._graph}, T={self._window})"


def window_graph_for(step_path: str | Path) -> Path:
    """Where the exporter puts the window graph of the step graph ``step_path``."""
    p = Path(step_path)
    stem = p.name[: -len(".onnx")] if p.name.endswith(".onnx") else p.name
    return p.with_name(f"{stem}.window.onnx")


def load_pair(step_path: str | Path, threads: int = 1) -> tuple[ScottiRuntime, ScottiRuntime]:
    """The step graph and its window graph, checked to come from the same export."""
    step = ScottiRuntime(step_path, threads)
    window_path = window_graph_for(step_path)
    if not window_path.exists():
        msg = f"no window graph {window_path.name} next to {step.path.name}"
        raise ModelError(msg)
    window = ScottiRuntime(window_path, threads)
    if step.graph != "step" or window.graph != "window":
        msg = f"{step.path.name} must be a step graph and {window_path.name} a window graph"
        raise ModelContractError(msg)
    # Same shape and, where the cards say, the same model config (the cards may
    # differ in when each graph was written).
    if (step.window, step.embed_dim) != (window.window, window.embed_dim) or step.card.get(
        "config"
    ) != window.card.get("config"):
        msg = f"{window_path.name} and {step.path.name} come from different exports"
        raise ModelContractError(msg)
    return step, window


def _as_f32(x: npt.ArrayLike, shape: tuple[int, ...], what: str) -> F32:
    a = np.ascontiguousarray(x, dtype=np.float32)
    if a.shape != shape:
        msg = f"{what} must be {shape}, got {a.shape}"
        raise ModelInputError(msg)
    return a
