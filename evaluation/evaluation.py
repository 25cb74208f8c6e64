"""Evaluate a model the way the daemon runs it: labelled session files replayed
through the live path, each prediction scored against the label of its time.

The path is the daemon's, step by step and as fast as the model allows:
``StreamDecoder`` -> ``FrameAssembler`` -> ``Pairing`` -> ``Window`` (the
streaming step graph with its embedding cache). A prediction made from the
frames t-T..t-1 is for time t, so it is scored against the label record of
the frame after the newest one in its window. The first T labelled frames of
a session therefore have no prediction (the window warms up on T frames and
the first prediction is for frame T).

``every=K`` > 1 scores every K-th prediction time instead, through the window
graph in batches (``evaluation.sampling``): same decoding, assembly, pairing
and restarts, a fraction of the model time.

No torch, no asyncio: ``scotti eval`` and the experiment drivers use it.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np
import numpy.typing as npt
from scotti.daemon.errors import DaemonError
from scotti.daemon.pairing import PairedFrame, Pairing, PairingConfig
from scotti.daemon.window import Window
from scotti.evaluation.sampling import Prediction, SampledTrack, window_timing
from scotti.firmware_protocol.assembly import FrameAssembler
from scotti.firmware_protocol.framing import StreamDecoder
from scotti.firmware_protocol.packets import FrameRows
from scotti.firmware_protocol.session import LabelRecord, PacketRecord, SessionReader
from scotti.firmware_protocol.wrap import seq_delta
from scotti.models import metrics
from scotti.models.contract import ACTIONS, NO_ACTION, NUM_ACTIONS, NUM_KEYPOINTS, has_progress
from scotti.models.ood import flag_shares
from scotti.models.runtime import ScottiRuntime, load_pair

F32 = npt.NDArray[np.float32]
I64 = npt.NDArray[np.int64]
RANDOM_SEED: Final = 0  # the random baseline's draws, fixed so that reruns agree
TRANSITION: Final = "transition"  # per-action row of frames labelled NO_ACTION


class EvaluationError(DaemonError):
    """A mistake in what was asked to evaluate: one line for the user."""


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
        progress = _progress_true(labels)
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
class SessionReplay:
    """What one session gave: counts along the path and the aligned frames."""

    path: str
    subject: str  # the header's subject id, else the file's stem (as training names it)
    labels: int = 0  # label records in the file
    pairs: int = 0  # paired frames the window took
    predictions: int = 0  # predictions made (with --every K: the scored ones)
    evaluated: int = 0  # predictions whose time has a label
    unlabelled: int = 0  # predictions for a time without a label (the last one, gaps)
    window_restarts: int = 0
    decode_errors: int = 0
    degraded_pairs: int = 0  # pairs with a held, filled or patched foot
    step_ms: list[float] = field(default_factory=list, repr=False)  # step graph only
    window_batches: list[tuple[float, int]] = field(default_factory=list, repr=False)
    frames: FrameSet = field(default_factory=FrameSet.empty, repr=False)
    made: list[Prediction] = field(default_factory=list, repr=False)  # in time order

    def summary(self) -> dict[str, Any]:
        keys = ("path", "subject", "labels", "pairs", "predictions", "evaluated", "unlabelled")
        out = {k: getattr(self, k) for k in keys}
        out |= {
            "window_restarts": self.window_restarts,
            "decode_errors": self.decode_errors,
            "degraded_pairs": self.degraded_pairs,
        }
        return out


def replay_session(
    path: str | Path,
    runtime: ScottiRuntime,
    pairing: PairingConfig | None = None,
    *,
    every: int = 1,
) -> SessionReplay:
    """Replay one session file through the daemon's path; score against its labels."""
    return replay_session_models(path, [runtime], pairing, every=every)[0]


def window_graphs(runtimes: Sequence[ScottiRuntime]) -> list[ScottiRuntime]:
    """The window graph next to each step graph (``--every K``); ``load_pair`` checks that
    it exists and comes from the same export (a one-line ModelError if not)."""
    return [load_pair(runtime.path, runtime.threads)[1] for runtime in runtimes]


def replay_session_models(
    path: str | Path,
    runtimes: Sequence[ScottiRuntime],
    pairing: PairingConfig | None = None,
    *,
    every: int = 1,
    windows: Sequence[ScottiRuntime] | None = None,
) -> list[SessionReplay]:
    """One replay, several models: the bytes are decoded, assembled and paired once,
    and every paired frame goes into each model's own window (nothing is shared
    between the models but the pairs). One ``SessionReplay`` per runtime.

    ``every`` > 1: every ``every``-th prediction through the window graphs
    ``windows`` (default: those next to ``runtimes``) instead of the step graph."""
    if every < 1:
        msg = f"--every must be at least 1, got {every}"
        raise EvaluationError(msg)
    decoder = StreamDecoder()
    assembler = FrameAssembler()
    pairs = Pairing(pairing)
    labels: list[LabelRecord] = []
    clock = _SeqClock()
    with SessionReader(path) as reader:
        subject = _subject_of(reader.header.subject) or Path(path).stem
        tracks: list[_Track | SampledTrack]
        if every == 1:
            tracks = [_Track(Window(r), SessionReplay(str(path), subject)) for r in runtimes]
        else:
            graphs = window_graphs(runtimes) if windows is None else windows
            tracks = [SampledTrack(w, every, SessionReplay(str(path), subject)) for w in graphs]

        def take(pair: PairedFrame) -> None:
            ext = clock.unwrap(pair.seqs[0] if pair.seqs[0] >= 0 else pair.seqs[1])
            for track in tracks:
                track.take(pair, ext)

        for record in reader:
            if isinstance(record, LabelRecord):
                labels.append(record)
                continue
            assert isinstance(record, PacketRecord)
            for packet in decoder.feed(record.data):
                if isinstance(packet, FrameRows):
                    for frame in assembler.push(packet, record.t_ns):
                        for pair in pairs.push(frame):
                            take(pair)
        for frame in assembler.flush():
            for pair in pairs.push(frame):
                take(pair)
        for pair in pairs.flush():
            take(pair)
    for track in tracks:
        track.finish()
        out = track.out
        out.labels = len(labels)
        out.made = track.made
        out.predictions = len(out.made)
        out.window_restarts = track.restarts
        out.decode_errors = decoder.counters.errors
        out.frames, out.unlabelled = _align(track.made, labels)
        out.evaluated = len(out.frames)
    return [t.out for t in tracks]


@dataclass
class _Track:
    """One model's window over the shared pairs, and what it predicted."""

    window: Window
    out: SessionReplay
    made: list[Prediction] = field(default_factory=list)

    def take(self, pair: PairedFrame, ext: int | None) -> None:
        if pair.restart:
            self.window.restart()
        start = time.perf_counter()
        result = self.window.push(pair.counts).result
        self.out.step_ms.append((time.perf_counter() - start) * 1e3)
        self.out.pairs += 1
        self.out.degraded_pairs += bool(pair.flags)
        if result is not None and ext is not None:
            self.made.append(
                Prediction(ext + 1, result.pose, result.action_probs, result.progress, result.flags)
            )

    @property
    def restarts(self) -> int:
        return self.window.restarts

    def finish(self) -> None:
        """Nothing is pending: every step ran as its pair came."""


class _SeqClock:
    """Unwraps the u16 seqs of successive pairs (and labels) onto one axis."""

    def __init__(self) -> None:
        self._raw: int | None = None
        self._ext = 0

    def unwrap(self, seq: int) -> int | None:
        if seq < 0:
            return None
        if self._raw is None:
            self._raw, self._ext = seq, seq
        else:
            self._ext += seq_delta(seq, self._raw)
            self._raw = seq
        return self._ext


def _align(made: list[Prediction], labels: list[LabelRecord]) -> tuple[FrameSet, int]:
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


def _progress_true(labels: Sequence[LabelRecord]) -> npt.NDArray[np.float64]:
    """Progress counts only where it is defined: a repeated action (as in training's loss)."""
    return np.array(
        [lb.progress if has_progress(lb.action) else np.nan for lb in labels], dtype=np.float64
    )


def _subject_of(subject: dict[str, Any] | None) -> str | None:
    if not subject:
        return None
    for key in ("id", "name", "subject_id"):  # the rule training uses, then the file stem
        if key in subject:
            return str(subject[key])
    return None


# --- scores ------------------------------------------------------------------


def task_metrics(frames: FrameSet) -> dict[str, float | int]:
    """The four tasks' figures (MPJPE and MPJAE for pose) over one set of frames."""
    # Frames with any labelled keypoint; the metrics leave out missing ones (NaN).
    pose_ok = np.any(np.all(np.isfinite(frames.pose_true), axis=2), axis=1)
    return {
        "mpjpe_mm": metrics.mpjpe_mm(frames.pose_pred, frames.pose_true, pose_ok),
        "mpjae_deg": metrics.mpjae_deg(frames.pose_pred, frames.pose_true, pose_ok),
        "action_accuracy": metrics.action_accuracy(frames.action_pred, frames.action_true),
        "progress_mse": metrics.progress_mse(frames.progress_pred, frames.progress_true),
        "app": metrics.app(frames.progress_pred, frames.progress_true),
        "frames": len(frames),
        "frames_action": int(metrics.action_mask(frames.action_true).sum()),
        "frames_progress": int(metrics.progress_mask(frames.progress_true).sum()),
    }


def random_baseline(frames: FrameSet, seed: int = RANDOM_SEED) -> dict[str, float]:
    """Uniform random progress (and action) on the same frames: the paper's chance row."""
    rng = np.random.default_rng(seed)
    progress = rng.uniform(0.0, 1.0, len(frames))
    action = rng.integers(0, NUM_ACTIONS, len(frames)).astype(np.int64)
    return {
        "action_accuracy": metrics.action_accuracy(action, frames.action_true),
        "progress_mse": metrics.progress_mse(progress, frames.progress_true),
        "app": metrics.app(progress, frames.progress_true),
    }


def score(frames: FrameSet) -> dict[str, Any]:
    """Overall and per-action figures, confusion matrix, precision-margin curve.

    Standing is scored like any action (accuracy, its row of the confusion
    matrix); its progress figures are NaN (no frame has a progress label).
    Frames labelled as a transition get their own row, ``transition``.
    """
    curve = metrics.precision_margin(frames.progress_pred, frames.progress_true)
    per_action = {
        name: task_metrics(frames.subset(frames.action_true == a)) for a, name in enumerate(ACTIONS)
    }
    per_action[TRANSITION] = task_metrics(frames.subset(frames.action_true == NO_ACTION))
    return {
        "metrics": task_metrics(frames),
        "per_action": per_action,
        "confusion": {
            "actions": list(ACTIONS),
            "rows": "true action",
            "columns": "predicted action",
            "matrix": metrics.confusion_matrix(frames.action_pred, frames.action_true).tolist(),
        },
        "precision_margin": {
            "app": curve.app,
            "margins": curve.margins.tolist(),
            "precision": curve.precision.tolist(),
        },
        "random_baseline": random_baseline(frames),
    }


def evaluate_sessions(
    paths: Sequence[str | Path],
    runtime: ScottiRuntime,
    pairing: PairingConfig | None = None,
    *,
    every: int = 1,
) -> dict[str, Any]:
    """Replay every session, pool their frames, and score them (JSON-ready)."""
    return evaluate_models(paths, [runtime], pairing, every=every)[0]


def evaluate_models(
    paths: Sequence[str | Path],
    runtimes: Sequence[ScottiRuntime],
    pairing: PairingConfig | None = None,
    *,
    every: int = 1,
    on_session: Callable[[int, int, Path, float], None] | None = None,
) -> list[dict[str, Any]]:
    """``evaluate_sessions`` for several models over one replay of each session.

    ``on_session(done, total, path, seconds)`` after each session: a long run's progress.
    """
    if every < 1:
        msg = f"--every must be at least 1, got {every}"
        raise EvaluationError(msg)
    windows = window_graphs(runtimes) if every > 1 else None
    per_session = []
    for i, p in enumerate(paths):
        started = time.perf_counter()
        per_session.append(
            replay_session_models(p, runtimes, pairing, every=every, windows=windows)
        )
        if on_session is not None:
            on_session(i + 1, len(paths), Path(p), time.perf_counter() - started)
    return [
        _report(
            runtime,
            [replays[i] for replays in per_session],
            every,
            windows[i] if windows else None,
        )
        for i, runtime in enumerate(runtimes)
    ]


def _report(
    runtime: ScottiRuntime,
    replays: list[SessionReplay],
    every: int,
    window_graph: ScottiRuntime | None,
) -> dict[str, Any]:
    frames = FrameSet.concat([r.frames for r in replays])
    report: dict[str, Any] = {
        "model": {
            "path": str(runtime.path),
            "sha256": runtime.sha256,
            "window": runtime.window,
            "embed_dim": runtime.embed_dim,
            "threads": runtime.threads,
        },
        "every": every,
        "graph": "step" if window_graph is None else "window",
        "sessions": [r.summary() | {"metrics": task_metrics(r.frames)} for r in replays],
        "subjects": sorted({r.subject for r in replays}),
    }
    if window_graph is None:
        steps = np.array([ms for r in replays for ms in r.step_ms], dtype=np.float64)
        report["step_ms"] = {
            "median": float(np.median(steps)) if steps.size else float("nan"),
            "p99": float(np.percentile(steps, 99)) if steps.size else float("nan"),
            "steps": int(steps.size),
        }
    else:
        report["model"]["window_graph"] = {
            "path": str(window_graph.path),
            "sha256": window_graph.sha256,
        }
        # Batched throughput, not the latency of one streaming step: named apart on purpose.
        batches = [b for r in replays for b in r.window_batches]
        report["window_ms_per_prediction"] = window_timing(batches)
    report |= score(frames)
    report["ood"] = flag_shares([m.flags for r in replays for m in r.made])  # every prediction
    return report
