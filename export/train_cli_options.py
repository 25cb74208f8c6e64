"""``scotti train``'s command line read into a model config and TrainOptions, each value
checked: a mistake is one line (TrainCliError, exit status 2), never a traceback."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from scotti.export.errors import ExportError
from scotti.export.graph_weights import has_folded_norm
from scotti.export.losses import LossWeights
from scotti.export.model import ScottiConfig
from scotti.export.train_args import CONFIG_PRESETS
from scotti.export.train_options import TrainOptions


class TrainCliError(ExportError):
    """A mistake in the command line or its inputs: one line, exit status 2."""


def parse_config(text: str) -> ScottiConfig:
    if text in CONFIG_PRESETS:
        return ScottiConfig.from_dict(CONFIG_PRESETS[text])
    source = text
    if not text.lstrip().startswith("{"):
        path = Path(text)
        if not path.is_file():
            msg = f"--config {text!r} is not a preset ({', '.join(CONFIG_PRESETS)}) nor a file"
            raise TrainCliError(msg)
        source = path.read_text()
    try:
        values = json.loads(source)
    except json.JSONDecodeError as exc:
        msg = f"--config is not valid JSON: {exc}"
        raise TrainCliError(msg) from None
    if not isinstance(values, dict):
        msg = "--config JSON must be an object"
        raise TrainCliError(msg)
    return ScottiConfig.from_dict(values)


def parse_loss_weights(text: str) -> LossWeights:
    """'POSE,ACTION,PROGRESS' -> LossWeights; each >= 0 and not all 0."""
    try:
        pose, action, progress = (float(x) for x in text.split(","))
    except ValueError:
        msg = f"--loss-weights wants three numbers POSE,ACTION,PROGRESS, got {text!r}"
        raise TrainCliError(msg) from None
    values = (pose, action, progress)
    # not (x >= 0) also catches NaN, which would poison every step.
    if any(not (x >= 0.0) or x == float("inf") for x in values) or sum(values) == 0.0:
        msg = f"--loss-weights must be finite, >= 0 and not all 0, got {text!r}"
        raise TrainCliError(msg)
    return LossWeights(pose=pose, action=action, progress=progress)


def tempo_range(text: str, flag: str = "--tempo-range") -> tuple[float, float]:
    """``--tempo-range LO,HI``: 0 < LO <= 1 <= HI <= 3 (a tempo of 1 must be drawable)."""
    try:
        low, high = (float(v) for v in text.split(","))
    except ValueError:
        msg = f"{flag} must be two numbers LO,HI such as 0.65,1.3, got {text!r}"
        raise TrainCliError(msg) from None
    if not (0.0 < low <= 1.0 <= high <= 3.0):  # also catches NaN
        msg = f"{flag} must have 0 < LO <= 1 <= HI <= 3, got {text!r}"
        raise TrainCliError(msg)
    return low, high


def options_from_args(args: argparse.Namespace) -> TrainOptions:
    """The run's TrainOptions from the command line, each value checked (TrainCliError)."""
    for name in ("epochs", "batch", "chunk", "stride", "val_stride", "threads"):
        if getattr(args, name) < 1:
            msg = f"--{name.replace('_', '-')} must be at least 1"
            raise TrainCliError(msg)
    for name in ("workers", "patience"):
        if getattr(args, name) < 0:
            msg = f"--{name} must be at least 0"
            raise TrainCliError(msg)
    if not 0.0 <= args.max_crosstalk <= 0.5:
        msg = f"--max-crosstalk must be between 0 and 0.5, got {args.max_crosstalk}"
        raise TrainCliError(msg)
    if not 0.0 <= args.sensor_transfer <= 1.0:  # also catches NaN
        msg = f"--sensor-transfer must be a share between 0 and 1, got {args.sensor_transfer}"
        raise TrainCliError(msg)
    if not 0.0 <= args.tempo_stretch <= 1.0:  # also catches NaN
        msg = f"--tempo-stretch must be a share between 0 and 1, got {args.tempo_stretch}"
        raise TrainCliError(msg)
    tempo_range_ = tempo_range(args.tempo_range)
    if not 0.0 <= args.tempo_extra <= 1.0 - args.tempo_stretch:  # also catches NaN
        msg = (
            "--tempo-extra must be a share between 0 and 1 - --tempo-stretch "
            f"({1.0 - args.tempo_stretch:g}), got {args.tempo_extra}"
        )
        raise TrainCliError(msg)
    tempo_extra_range = tempo_range(args.tempo_extra_range, "--tempo-extra-range")
    if not (args.ema == 0.0 or 0.0 < args.ema < 1.0):  # also catches NaN
        msg = f"--ema must be 0 (off) or a decay between 0 and 1, got {args.ema}"
        raise TrainCliError(msg)
    if not args.save_minutes >= 0.0:  # also catches NaN
        msg = f"--save-minutes must be at least 0 (0 = off), got {args.save_minutes}"
        raise TrainCliError(msg)
    if not args.min_delta >= 0.0:
        msg = f"--min-delta must be at least 0, got {args.min_delta}"
        raise TrainCliError(msg)
    if not args.keep_near >= 0.0:  # also catches NaN
        msg = f"--keep-near must be at least 0 (0 = off), got {args.keep_near}"
        raise TrainCliError(msg)
    if args.keep_near > 0.0 and args.init is None:
        msg = "--keep-near keeps the model near its --init weights: give --init"
        raise TrainCliError(msg)
    return TrainOptions(
        epochs=args.epochs,
        batch=args.batch,
        chunk=args.chunk,
        stride=args.stride,
        val_stride=args.val_stride,
        lr=args.lr,
        weight_decay=args.weight_decay,
        max_shift=args.max_shift,
        max_crosstalk=args.max_crosstalk,
        sensor_transfer=args.sensor_transfer,
        tempo_stretch=args.tempo_stretch,
        tempo_range=tempo_range_,
        tempo_extra=args.tempo_extra,
        tempo_extra_range=tempo_extra_range,
        loss_weights=parse_loss_weights(args.loss_weights),
        seed=args.seed,
        max_minutes=args.max_minutes,
        save_minutes=args.save_minutes,
        progress_bar=not args.no_progress and sys.stderr.isatty(),
        freeze=tuple(args.freeze),
        precision=args.precision,
        workers=args.workers,
        patience=args.patience,
        min_delta=args.min_delta,
        ema=args.ema,
        keep_near=args.keep_near,
        keep_near_pass=args.keep_near_pass,
        norm_statistics=args.norm_statistics or "batch",  # or as the weights say: run_training
    )


def default_norm_statistics(ckpt: dict[str, Any] | None, init: dict[str, Any] | None) -> str:
    """--norm-statistics when not given: a resumed run's own; for --init, 'kept' where the
    weights' batch norm has a graph's folded statistics (graph_weights.has_folded_norm:
    batch statistics would standardise its input again), 'batch' otherwise."""
    if ckpt is not None:
        return str(ckpt.get("options", {}).get("norm_statistics", "batch"))
    if init is not None and has_folded_norm(init["model"]):
        return "kept"
    return "batch"
