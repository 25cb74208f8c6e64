"""``scotti train SESSIONS_OR_DIRS... -o runs/NAME``: train SCOTTI on labelled session files.

Writes runs/NAME/last.pt after every epoch (and when --max-minutes runs
out), runs/NAME/best.pt at the best validation loss, and runs/NAME/history.jsonl.
``--resume`` continues from runs/NAME/last.pt exactly where it stopped.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import torch
from scotti.export.checkpoint import load_checkpoint
from scotti.export.data import SessionArrays, find_sessions, load_session
from scotti.export.errors import ExportError
from scotti.export.losses import LossWeights
from scotti.export.model import ModelConfigError, Scotti, ScottiConfig
from scotti.export.train import (
    FREEZE_GROUPS,
    Trainer,
    TrainOptions,
    load_initial_weights,
    measure_throughput,
)
from scotti.export.windows import WindowDataset, split_by_subject

log = logging.getLogger("scotti.train")

# Named model sizes. "paper" is the paper's E=512; "small" trains in hours on
# a CPU; "tiny" is for tests and smoke runs only.
CONFIG_PRESETS: dict[str, dict[str, Any]] = {
    "paper": {},
    "small": {"embed_dim": 128, "layers": 2, "heads": 4, "head_hidden": 128},
    "tiny": {
        "embed_dim": 32,
        "layers": 1,
        "heads": 2,
        "head_hidden": 32,
        "conv_channels": [4, 8],
        "dropout": 0.0,
    },
}


class TrainCliError(ExportError):
    """A mistake in the command line or its inputs: one line, exit status 2."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    d = TrainOptions()
    parser.add_argument("sessions", nargs="+", type=Path, help="session files or directories")
    parser.add_argument("-o", "--output", type=Path, required=True, help="run directory")
    parser.add_argument(
        "--config",
        default=None,
        help="model size: "
        + "|".join(CONFIG_PRESETS)
        + ", a JSON object or a .json file"
        + " (default small; with --init, the checkpoint's)",
    )
    parser.add_argument(
        "--init",
        type=Path,
        default=None,
        metavar="CHECKPOINT",
        help="start from this checkpoint's weights (fine-tuning); fresh optimiser and schedule",
    )
    parser.add_argument(
        "--freeze",
        nargs="+",
        choices=FREEZE_GROUPS,
        default=[],
        help="keep these parts as they are (with --init: fine-tune the rest)",
    )
    parser.add_argument("--epochs", type=int, default=d.epochs)
    parser.add_argument("--batch", type=int, default=d.batch, help="windows per step")
    parser.add_argument(
        "--chunk", type=int, default=d.chunk, help="consecutive windows sharing one CNN pass"
    )
    parser.add_argument("--stride", type=int, default=d.stride, help="slots between windows")
    parser.add_argument("--val-stride", type=int, default=d.val_stride)
    parser.add_argument("--lr", type=float, default=d.lr)
    parser.add_argument("--weight-decay", type=float, default=d.weight_decay)
    parser.add_argument("--max-shift", type=int, default=d.max_shift, help="augmentation, taxels")
    w = d.loss_weights
    parser.add_argument(
        "--loss-weights",
        default=f"{w.pose:g},{w.action:g},{w.progress:g}",
        metavar="POSE,ACTION,PROGRESS",
        help="weights of the three losses (paper: 0.01,1,1); 0 switches a task off",
    )
    parser.add_argument("--seed", type=int, default=d.seed)
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    parser.add_argument("--max-minutes", type=float, default=0.0, help="0 = no time limit")
    parser.add_argument("--test-subjects", nargs="*", default=None, help="held-out subjects")
    parser.add_argument("--test-fraction", type=float, default=0.2)
    parser.add_argument("--resume", action="store_true", help="continue from OUTPUT/last.pt")
    parser.add_argument("--cache", type=Path, default=None, help="decoded-session cache dir")
    parser.add_argument("--allow-invalid", action="store_true", help="keep windows with gaps")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument(
        "--benchmark",
        type=int,
        default=0,
        metavar="STEPS",
        help="only measure naive vs chunked training throughput over STEPS batches",
    )


def run(args: argparse.Namespace) -> int:
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    try:
        return _run(args)
    except (ExportError, ModelConfigError) as exc:
        print(f"scotti train: {exc}", file=sys.stderr)
        return 2


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


def _options(args: argparse.Namespace) -> TrainOptions:
    for name in ("epochs", "batch", "chunk", "stride", "val_stride", "threads"):
        if getattr(args, name) < 1:
            msg = f"--{name.replace('_', '-')} must be at least 1"
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
        loss_weights=parse_loss_weights(args.loss_weights),
        seed=args.seed,
        max_minutes=args.max_minutes,
        progress_bar=not args.no_progress and sys.stderr.isatty(),
        freeze=tuple(args.freeze),
    )


def _run(args: argparse.Namespace) -> int:
    torch.set_num_threads(args.threads)
    opts = _options(args)
    out: Path = args.output
    resume_from = out / "last.pt"
    ckpt = load_checkpoint(resume_from) if args.resume and resume_from.is_file() else None
    if args.resume and ckpt is None:
        log.info("no %s yet: starting a new run", resume_from)
    init = load_checkpoint(args.init) if args.init is not None and ckpt is None else None
    if init is not None and args.config is not None:
        msg = "--init takes the model size from its checkpoint; leave out --config"
        raise TrainCliError(msg)
    if ckpt is not None:
        cfg = ScottiConfig.from_dict(ckpt["config"])
    elif init is not None:
        cfg = ScottiConfig.from_dict(init["config"])
    else:
        cfg = parse_config(args.config or "small")

    cache = args.cache or out.parent / ".session-cache"
    sessions = [load_session(p, cache) for p in find_sessions(args.sessions)]
    _log_sessions(sessions)
    split = split_by_subject(
        sessions, args.test_subjects, test_fraction=args.test_fraction, seed=opts.seed
    )
    train_set = WindowDataset(split.train, cfg.window, allow_invalid=args.allow_invalid)
    test_set = WindowDataset(split.test, cfg.window, allow_invalid=args.allow_invalid)
    if train_set.count(opts.stride) == 0:
        msg = f"no usable training windows of {cfg.window} frames in the given sessions"
        raise TrainCliError(msg)
    training_data: dict[str, Any] = {
        "files": [s.path for s in sessions],
        "subjects": sorted({s.subject for s in sessions}),
        "split": split.describe(),
        "frames": sum(len(s) for s in sessions),
        "windows": {"train": train_set.count(1), "test": test_set.count(1)},
        "train_targets": train_set.target_counts(),  # windows per action: no class balancing
        "problems": _sum_counters(sessions),
    }
    if args.init is not None:
        training_data["init"] = str(
            ckpt["training_data"].get("init", args.init) if ckpt else args.init
        )
    if ckpt is not None and sorted(ckpt["training_data"]["files"]) != sorted(
        training_data["files"]
    ):
        msg = f"--resume with other session files than {resume_from} was trained on"
        raise TrainCliError(msg)
    log.info(
        "%d sessions, subjects train %s / test %s (%s split), windows train %d / test %d",
        len(sessions),
        ",".join(split.train_subjects),
        ",".join(split.test_subjects) or "-",
        split.kind,
        train_set.count(1),
        test_set.count(1),
    )
    targets = training_data["train_targets"]
    total = max(1, sum(targets.values()))
    log.info(
        "training windows per target action: %s",
        ", ".join(f"{name} {n} ({100 * n / total:.1f} %)" for name, n in targets.items()),
    )

    torch.manual_seed(opts.seed)
    model = Scotti(cfg)
    if init is not None:
        for note in load_initial_weights(model, init["model"]):
            log.info("--init: %s", note)
        log.info("--init: weights from %s%s", args.init, _frozen_note(opts.freeze))
    if args.benchmark:
        rates = measure_throughput(model, train_set, replace(opts, max_shift=0), args.benchmark)
        print(
            f"E={cfg.embed_dim} T={cfg.window} batch={opts.batch} chunk={opts.chunk} "
            f"stride={opts.stride} threads={args.threads}: naive {rates['naive']:.1f} "
            f"windows/s, chunked {rates['chunked']:.1f} windows/s, x{rates['ratio']:.1f}"
        )
        return 0
    trainer = Trainer(
        model,
        train_set,
        test_set if test_set.count(1) else None,
        opts,
        run_dir=out,
        training_data=training_data,
    )
    if ckpt is not None:
        _warn_changed_options(ckpt.get("options", {}), opts.to_dict())
        trainer.restore(ckpt)
        log.info(
            "resuming %s at epoch %d step %d",
            resume_from,
            trainer.state.epoch + 1,
            trainer.state.step_in_epoch,
        )
    out.mkdir(parents=True, exist_ok=True)
    status = trainer.fit()
    log.info("%s: %s after %d epochs, checkpoint %s", out, status, trainer.state.epoch, resume_from)
    return 0


def _frozen_note(freeze: tuple[str, ...]) -> str:
    return f", {' and '.join(freeze)} frozen" if freeze else ""


def _warn_changed_options(before: dict[str, Any], now: dict[str, Any]) -> None:
    """Resuming with other batching or augmentation is allowed, but no longer exact."""
    ignore = {"epochs", "max_minutes", "progress_bar"}
    changed = sorted(k for k in now if k not in ignore and k in before and before[k] != now[k])
    if changed:
        log.warning(
            "resuming with changed %s: the run will not match an uninterrupted one",
            ", ".join(changed),
        )


def _log_sessions(sessions: list[SessionArrays]) -> None:
    for s in sessions:
        bad = {k: v for k, v in s.counters.items() if v}
        log.info(
            "%s: subject %s, %d frames%s", s.path, s.subject, len(s), f", {bad}" if bad else ""
        )


def _sum_counters(sessions: list[SessionArrays]) -> dict[str, int]:
    total: dict[str, int] = {}
    for s in sessions:
        for k, v in s.counters.items():
            total[k] = total.get(k, 0) + int(v)
    return total
