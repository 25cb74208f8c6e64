"""Sessions watched while a model trains (``scotti train --watch``): scored after every
epoch, never trained on, never picking ``best.pt``.

Validation says how a run does on people drawn like its corpus. A run can look
right there and fail where users meet the model: a from-scratch run validated
at 98.2 % read six squats of ``sim/scenes/squat.toml`` as standing, which only
the judging after its 94 minutes showed (docs/generalisation.md). Watched files
(the shipped scenes, people drawn unlike the corpus, labelled imports) are
scored at each epoch's end with the weights validation judges: accuracy, the
recall of each labelled action, APP and MPJPE, per file, into history.jsonl and
the log, so such a run can be stopped after its first epoch.

The scores are the training graph's on windows at the validation stride (no
progress calibration, no input checks or flags): an early warning, not the
judging, which replays the exported graph through the daemon's path
(``scotti eval``, experiments/wide_rule.py).

The same figures for any checkpoint or exported graph, without training:

    python -m scotti.export.watch runs/NAME/best.pt runs/scenes/squat.scotti [--stride 8]
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scotti.export.checkpoint import load_checkpoint
from scotti.export.data import SessionArrays, TrainingDataError, find_sessions, load_session
from scotti.export.errors import ExportError
from scotti.export.evaluate import predict
from scotti.export.graph_weights import checkpoint_from_graph
from scotti.export.model import ModelConfigError, Scotti, ScottiConfig
from scotti.export.windows import WindowDataset
from scotti.models import metrics
from scotti.models.contract import ACTIONS
from scotti.models.errors import ModelError

log = logging.getLogger("scotti.train")


@dataclass(frozen=True)
class Watched:
    """One watched session file, cut into windows."""

    name: str  # the file's stem (with its folder where two stems clash)
    windows: WindowDataset


def load_watched(
    paths: Sequence[Path],
    cache: Path | None,
    *,
    window: int,
    allow_invalid: bool,
    training: Sequence[SessionArrays],
) -> list[Watched]:
    """The watched files as windows; a file that is also a training session is refused
    (``TrainingDataError``): its scores would say nothing about the unseen."""
    files = list({p.resolve(): p for p in find_sessions(paths)}.values())  # each file once
    trained = {Path(s.path).resolve() for s in training}
    same = [str(p) for p in files if p.resolve() in trained]
    if same:
        msg = f"--watch names training sessions (watched files are never trained on): {same[0]}"
        raise TrainingDataError(msg)
    stems = [p.stem for p in files]
    watched = []
    for path in files:
        session = load_session(path, cache)
        name = path.stem if stems.count(path.stem) == 1 else f"{path.parent.name}/{path.stem}"
        watched.append(Watched(name, WindowDataset([session], window, allow_invalid=allow_invalid)))
    log.info(
        "watching %d session(s): %s",
        len(watched),
        ", ".join(f"{w.name} ({w.windows.count(1)} windows)" for w in watched),
    )
    return watched


def watch_scores(model: Scotti, windows: WindowDataset, stride: int) -> dict[str, Any]:
    """Accuracy, recall per labelled action, APP, progress MSE and MPJPE of one file."""
    out, labels = predict(model, windows, stride)
    if not labels:
        return {"windows": 0}
    action = out.action_logits.argmax(dim=1).numpy().astype(np.int64)
    true = labels["action"]
    recall = {
        name: float(np.mean(action[true == i] == i))
        for i, name in enumerate(ACTIONS)
        if np.any(true == i)
    }
    progress_true = np.where(true >= 0, labels["progress"], np.nan).astype(np.float64)
    pose = out.pose.numpy()
    pose_ok = np.isfinite(labels["keypoints"]).all(axis=2).any(axis=1)
    return {
        "windows": len(action),
        "action_accuracy": metrics.action_accuracy(action, true),
        "recall": recall,
        "app": metrics.app(out.progress.numpy(), progress_true),
        "progress_mse": metrics.progress_mse(out.progress.numpy(), progress_true),
        "mpjpe_mm": metrics.mpjpe_mm(pose, labels["keypoints"], pose_ok),
    }


def watch_record(
    model: Scotti, watched: Sequence[Watched], stride: int
) -> dict[str, dict[str, Any]]:
    """An epoch's ``watch`` record: each watched file's scores, by name."""
    return {w.name: watch_scores(model, w.windows, stride) for w in watched}


def watch_line(name: str, scores: dict[str, Any]) -> str:
    """One log line: ``watch squat: accuracy 20.3 %, APP 0.810; recall squat 17 %, ...``."""
    if not scores.get("windows"):
        return f"watch {name}: no labelled windows"
    recall = ", ".join(f"{a} {100 * r:.0f} %" for a, r in scores["recall"].items())
    return (
        f"watch {name}: accuracy {100 * scores['action_accuracy']:.1f} %, "
        f"APP {scores['app']:.3f}; recall {recall or '-'}"
    )


def model_of(path: Path) -> Scotti:
    """A training checkpoint's weights (the average where it has one), or an exported
    graph's read back out of it, in eval mode."""
    ckpt = checkpoint_from_graph(path) if path.suffix == ".onnx" else load_checkpoint(path)
    model = Scotti(ScottiConfig.from_dict(ckpt["config"]))
    model.load_state_dict(ckpt["model"])
    return model.eval()


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m scotti.export.watch",
        description="score a checkpoint (.pt) or an exported graph (.onnx) on session files "
        "as scotti train --watch does after every epoch",
    )
    parser.add_argument("model", type=Path, help="checkpoint (.pt) or step graph (.onnx)")
    parser.add_argument("sessions", nargs="+", type=Path, help="session files or directories")
    parser.add_argument("--stride", type=int, default=8, help="windows' stride (train_wide: 8)")
    parser.add_argument(
        "--cache", type=Path, default=None, help="decoded-session cache (default: none)"
    )
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    try:
        if args.stride < 1:
            msg = f"--stride must be at least 1, got {args.stride}"
            raise TrainingDataError(msg)
        model = model_of(args.model)
        watched = load_watched(
            args.sessions, args.cache, window=model.cfg.window, allow_invalid=False, training=()
        )
    except (ExportError, ModelConfigError, ModelError, OSError) as exc:
        print(f"watch: {exc}", file=sys.stderr)
        return 2
    for w in watched:
        print(watch_line(w.name, watch_scores(model, w.windows, args.stride)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
