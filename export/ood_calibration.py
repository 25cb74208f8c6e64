"""Calibrating the ``unfamiliar`` score at export: statistics from training windows,
the threshold from held-out ones.

The checkpoint names the subjects it was trained on and those it held out
(``training_data.split``: ``train_subjects``, and ``validation_subjects`` when
the trainer drew a validation split, else ``test_subjects``). The session
files given to ``scotti export --calibrate`` are grouped by subject; the
usable windows of the training subjects (as training draws them,
``WindowDataset``), thinned evenly to at most ``max_windows``, go through the
exported window graph, and each action's mean of their pooled vectors and the
shrunk covariance around those means are fitted (models/ood.py; a window's
action is its target slot's label, as training reads it). Each action's
threshold is the ``percentile`` of the distances to its mean of the held-out
subjects' windows the model calls that action (thinned evenly to at most
``held_out_windows``): about 1 % of the windows of people the model never saw
are called unfamiliar, by construction, and about 1 % of each action's. With
``scotti export --calibrate-as-trained`` both sides' windows are drawn as the
checkpoint's training drew them, through foreign insoles and at other tempi
(export/calibration_draws.py; docs/ood.md says what that trades).

The same windows also measure the input checks (models/input_checks.py):
the share of real windows flagged ``unloaded`` or ``out_of_range``, which
should be about 0, goes into the card.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scotti.export.calibration_draws import AS_RECORDED, InputDraws, drawn_window
from scotti.export.data import SessionArrays, find_sessions, load_session
from scotti.export.errors import ExportError
from scotti.export.windows import WindowDataset
from scotti.models import input_checks
from scotti.models.contract import ACTIONS, WINDOW
from scotti.models.ood import OodStats, fit
from scotti.models.runtime import ScottiRuntime


@dataclass(frozen=True)
class Calibration:
    """What ``scotti export --calibrate`` was asked for."""

    sessions: tuple[Path, ...]  # session files or directories
    percentile: float = 99.0  # of held-out window scores: the threshold
    # Training windows for the statistics (means, shrunk covariance), thinned evenly.
    # Not more: Ledoit-Wolf shrinks less the more windows it is given, and the flag
    # then trusts directions the simulated windows barely vary in and real insoles do.
    # Fitted on 40,000, the shipped weights' flag withheld 55 % of the real windows
    # instead of 22 % and published 45 % of the real walking instead of 79 %, with no
    # fewer wrong answers sent (docs/ood.md, "How much of it is the calibration's draw").
    max_windows: int = 4000
    cache_dir: Path | None = None  # decoded-session cache (training's --cache-dir)
    # Held-out windows for the thresholds (each action's percentile), thinned evenly:
    # all of them for a p1 run. At 4,000, about 450 walking windows set the walking
    # threshold, and the share of real walking the shipped model published moved by
    # 6 points (sd) with the draw; with all 39,181, 3 points.
    held_out_windows: int = 40000
    # The progress calibration (export/progress_fit.py) on the held-out subjects'
    # windows, thinned evenly to this many (0: none); an action predicted on fewer
    # than ``progress_min_windows`` of them keeps the head's output as it is.
    progress_windows: int = 20000
    progress_min_windows: int = 500
    # How the unfamiliar score's windows are drawn (InputDraws(): as recorded). With
    # ``as_trained`` export replaces them by the checkpoint's own (its ``options``).
    draws: InputDraws = field(default_factory=InputDraws)
    as_trained: bool = False


def split_subjects(training_data: Any) -> tuple[list[str], list[str], str]:
    """(training subjects, held-out subjects, which split held out) from a checkpoint."""
    split = training_data.get("split") if isinstance(training_data, dict) else None
    if not isinstance(split, dict) or not split.get("train_subjects"):
        msg = (
            "the checkpoint does not name its training subjects (training_data.split."
            "train_subjects): cannot calibrate the unfamiliar score"
        )
        raise ExportError(msg)
    # "validation_subjects" is what export/validation.py's Splits.describe writes.
    for key, name in (("validation_subjects", "validation"), ("test_subjects", "test")):
        if split.get(key):
            return list(split["train_subjects"]), list(split[key]), name
    msg = "the checkpoint names no held-out subjects (validation_subjects or test_subjects)"
    raise ExportError(msg)


def window_batches(
    sessions: Sequence[SessionArrays],
    max_windows: int,
    draws: InputDraws = AS_RECORDED,
    side: int = 0,
    batch: int = 64,
) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """At most ``max_windows`` usable windows, evenly over time, in batches: (b, T, H, 2W)
    float32 (a batch at a time: thousands of windows would take gigabytes at once) and
    (b,) the action of each window's target slot (slot t + T, ``WindowDataset``).
    With active ``draws`` each window is drawn as training drew it (``side`` seeds them)."""
    data = WindowDataset(sessions, WINDOW)
    stride = max(1, -(-data.count() // max(max_windows, 1)))
    starts = [(i, int(t)) for i in range(len(sessions)) for t in data.starts(i, stride=stride)]
    rng = draws.generator(side) if draws.active else None
    for k in range(0, len(starts), batch):
        chunk = starts[k : k + batch]
        if rng is not None:
            drawn = [drawn_window(data, i, t, draws, rng) for i, t in chunk]
            windows = np.stack([w for w, _ in drawn])
            actions = np.array([a for _, a in drawn], dtype=np.int64)
        else:
            windows = np.stack([sessions[i].frames[t : t + WINDOW] for i, t in chunk])
            actions = np.array([sessions[i].action[t + WINDOW] for i, t in chunk], dtype=np.int64)
        yield windows.astype(np.float32), actions


@dataclass(frozen=True)
class Measured:
    pooled: np.ndarray  # (n, E)
    actions: np.ndarray  # (n,) the windows' labels, contract.NO_ACTION for none
    predicted: np.ndarray  # (n,) the action the model calls each window
    input_flags: dict[str, float]  # share of the windows each input check flags


def measure(
    graph: ScottiRuntime,
    sessions: Sequence[SessionArrays],
    max_windows: int,
    draws: InputDraws = AS_RECORDED,
    side: int = 0,
) -> Measured:
    """Pooled vectors of the windows, their labels, and the share the input checks flag."""
    pooled, actions, predicted = [], [], []
    flagged = dict.fromkeys((input_checks.UNLOADED, input_checks.OUT_OF_RANGE), 0)
    for windows, labels in window_batches(sessions, max_windows, draws, side):
        result = graph.run_windows(windows, batch_size=len(windows))
        if result.pooled is None:
            msg = f"{graph.path.name} has no pooled output to calibrate"
            raise ExportError(msg)
        pooled.append(result.pooled)
        actions.append(labels)
        predicted.append(result.action_logits.argmax(axis=-1))
        for w in windows:
            for flag in input_checks.check_window(w).flags:
                flagged[flag] += 1
    if not pooled:
        none = np.zeros(0, np.int64)
        return Measured(np.zeros((0, graph.embed_dim), np.float32), none, none, {})
    out = np.concatenate(pooled)
    shares = {flag: n / len(out) for flag, n in flagged.items()}
    return Measured(out, np.concatenate(actions), np.concatenate(predicted), shares)


@dataclass(frozen=True)
class CalibrationSets:
    """The decoded sessions of the training and the held-out subjects."""

    train: list[SessionArrays]
    held_out: list[SessionArrays]
    held_kind: str  # "validation" or "test": which split of the checkpoint was held out


def gather(training_data: Any, request: Calibration) -> CalibrationSets:
    """The sessions to calibrate on, by the checkpoint's split (before any export work:
    a mistake here is one ``ExportError`` line, at once)."""
    train_ids, held_ids, held_kind = split_subjects(training_data)
    by_subject: dict[str, list[SessionArrays]] = {}
    for path in find_sessions(request.sessions):
        arrays = load_session(path, request.cache_dir)
        by_subject.setdefault(arrays.subject, []).append(arrays)
    train = [a for s in train_ids for a in by_subject.get(s, [])]
    held = [a for s in held_ids for a in by_subject.get(s, [])]
    for side, found, ids in (("training", train, train_ids), (held_kind, held, held_ids)):
        if not found:
            msg = (
                f"no session of the {side} subjects ({', '.join(ids[:5])}"
                f"{', ...' if len(ids) > 5 else ''}) among the calibration sessions"
            )
            raise ExportError(msg)
    return CalibrationSets(train, held, held_kind)


def calibrate(
    window_graph_path: Path, sets: CalibrationSets, request: Calibration, threads: int = 1
) -> OodStats:
    """Fit the OOD statistics of an exported window graph; one ``ExportError`` line on misfit."""
    graph = ScottiRuntime(window_graph_path, threads)
    draws = request.draws
    train = measure(graph, sets.train, request.max_windows, draws, side=0)
    held = measure(graph, sets.held_out, request.held_out_windows, draws, side=1)
    if len(train.pooled) < 2 or len(held.pooled) < 1:
        msg = "too few usable windows in the calibration sessions"
        raise ExportError(msg)
    stats = fit(
        train.pooled, held.pooled, request.percentile, train.actions, held.predicted, ACTIONS
    )
    summary = {
        **stats.summary,
        "train_subjects": sorted({a.subject for a in sets.train}),
        "held_out_subjects": sorted({a.subject for a in sets.held_out}),
        "held_out_split": sets.held_kind,
        "windows_drawn": draws.describe(),
        "input_checks_on_held_out": held.input_flags,
        "input_checks_on_train": train.input_flags,
    }
    return OodStats(stats.mean, stats.whitening, stats.threshold, summary, stats.action_means)
