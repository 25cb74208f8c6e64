"""``scotti train SESSIONS_OR_DIRS... -o runs/NAME``: train SCOTTI on labelled session files.

Writes runs/NAME/last.pt after every epoch, every --save-minutes, and when
--max-minutes runs out or SIGTERM/SIGINT stops the run (after the step in
hand; exit status 0), runs/NAME/best.pt at the best validation loss, runs/NAME/history.jsonl,
and at the end runs/NAME/test.json (best.pt on the test subjects).
``--resume`` continues from runs/NAME/last.pt exactly where it stopped. A
run directory that holds a run is refused unless ``--resume``, or ``--force``
(start over: the old run's files are deleted; export/run_dir.py).
Under ``torchrun --nproc-per-node N -m scotti.cli.main train ...`` it trains
with N processes (export/distributed.py).
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import os
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import torch
from scotti.export import distributed
from scotti.export.anchor import Anchor
from scotti.export.checkpoint import load_checkpoint
from scotti.export.devices import check_precision, resolve_device
from scotti.export.distributed import DistContext, context_from_environment
from scotti.export.errors import ExportError
from scotti.export.graph_weights import checkpoint_from_graph
from scotti.export.model import ModelConfigError, Scotti, ScottiConfig
from scotti.export.run_data import RunData, load_sessions, prepare, same_session_files
from scotti.export.run_dir import check_run_dir, clear_run
from scotti.export.stop_signals import stop_on_signals
from scotti.export.subnormals import flushing_denormals
from scotti.export.test_report import write_test_report
from scotti.export.throughput import measure_precisions, measure_throughput
from scotti.export.train import Trainer, TrainOptions, load_initial_weights
from scotti.export.train_args import CONFIG_PRESETS, add_arguments
from scotti.export.train_cli_options import (
    TrainCliError,
    default_norm_statistics,
    options_from_args,
    parse_config,
)
from scotti.export.validation import predates_validation_split
from scotti.export.watch import load_watched

log = logging.getLogger("scotti.train")

__all__ = ["CONFIG_PRESETS", "add_arguments", "parse_config", "run", "run_training", "train"]


def run(args: argparse.Namespace) -> int:
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    try:
        return _run(args)
    except (ExportError, ModelConfigError) as exc:
        print(f"scotti train: {exc}", file=sys.stderr)
        return 2


def _run(args: argparse.Namespace) -> int:
    run_training(args)
    return 0


def run_training(args: argparse.Namespace) -> Trainer | None:
    """This process's part of the run: alone, or one rank of torchrun's (its environment)."""
    ctx = context_from_environment()
    if not ctx.is_main:
        logging.getLogger().setLevel(logging.WARNING)  # rank 0 alone logs
    if args.benchmark and ctx.distributed:
        msg = "--benchmark measures one process: run it without torchrun"
        raise TrainCliError(msg)
    device = resolve_device(args.device, ctx.local_rank)
    check_precision(args.precision, device)
    with distributed.process_group(ctx, device), flushing_denormals() as flushing:
        if not flushing:
            log.info("this CPU cannot flush subnormal floats: training may slow as weights decay")
        trainer = train(args, ctx=ctx, device=device)
        if trainer is not None:
            # DDP's reducer goes while its process group is alive. Left to the end of
            # the interpreter, a rank once aborted there ("terminate called without an
            # active exception", the torchrun test under load; cause not proven).
            trainer.forward = distributed.unwrap(trainer.forward)
        return trainer


def train(
    args: argparse.Namespace,
    *,
    ctx: DistContext | None = None,
    device: torch.device | None = None,
) -> Trainer | None:
    """The whole run of ``scotti train`` in this process; None for ``--benchmark``."""
    ctx = ctx or DistContext()
    device = device or torch.device("cpu")
    torch.set_num_threads(args.threads)
    opts = options_from_args(args)
    out: Path = args.output
    if not args.benchmark:  # a benchmark writes nothing there
        check_run_dir(out, resume=args.resume, force=args.force)
    resume_from = out / "last.pt"
    ckpt = load_checkpoint(resume_from) if args.resume and resume_from.is_file() else None
    if args.resume and ckpt is None:
        log.info("no %s yet: starting a new run", resume_from)
    init = _initial_checkpoint(args.init) if args.init is not None and ckpt is None else None
    if args.norm_statistics is None:
        opts = dataclasses.replace(opts, norm_statistics=default_norm_statistics(ckpt, init))
    if init is not None and args.config is not None:
        msg = "--init takes the model size from its checkpoint; leave out --config"
        raise TrainCliError(msg)
    if ckpt is not None:
        cfg = ScottiConfig.from_dict(ckpt["config"])
    elif init is not None:
        cfg = ScottiConfig.from_dict(init["config"])
    else:
        cfg = parse_config(args.config or "small")
        if args.arch is not None:
            cfg = dataclasses.replace(cfg, arch=args.arch)
    if args.arch is not None and args.arch != cfg.arch:
        msg = f"--arch {args.arch}: the checkpoint's model is the {cfg.arch} form"
        raise TrainCliError(msg)

    data = _load_data(args, ckpt, cfg, opts, ctx)
    training_data = data.training_data()
    if args.init is not None:
        training_data["init"] = str(
            ckpt["training_data"].get("init", args.init) if ckpt else args.init
        )
    if ckpt is not None and not same_session_files(ckpt["training_data"], training_data):
        msg = f"--resume with other session files than {resume_from} was trained on"
        raise TrainCliError(msg)
    if ckpt is not None and sorted(ckpt["training_data"]["files"]) != sorted(
        training_data["files"]
    ):  # the same files in another folder: the checkpoints from here on record this one
        log.info("resuming on the same session files, moved: %s", _folder(training_data))

    torch.manual_seed(opts.seed)
    model = Scotti(cfg)
    if init is not None:
        for note in load_initial_weights(model, init["model"]):
            log.info("--init: %s", note)
        log.info("--init: weights from %s%s", args.init, _frozen_note(opts.freeze))
    if args.benchmark:
        _benchmark(model, data, opts, args, device)
        return None
    if opts.keep_near > 0.0 and ctx.distributed:
        # Its pass runs the model outside DDP's wrapper, whose gradients DDP would not average.
        msg = "--keep-near trains in one process: run it without torchrun"
        raise TrainCliError(msg)
    anchor = _anchor(opts, model, init, training_data)
    if ctx.distributed:
        # The same weights everywhere (DDP checks), but each rank its own dropout draws.
        torch.manual_seed(opts.seed + 7919 * (ctx.rank + 1))
    watched = []
    if args.watch and ctx.is_main:  # scored on rank 0 only, as validation is
        cache = args.cache or args.output.parent / ".session-cache"
        watched = load_watched(
            args.watch,
            cache,
            window=model.cfg.window,
            allow_invalid=args.allow_invalid,
            training=data.sessions,
        )
    trainer = Trainer(
        model,
        data.train,
        data.validation if data.validation.count(1) else None,
        opts,
        run_dir=out,
        training_data=training_data,
        device=device,
        dist_ctx=ctx,
        watched=watched,
        anchor=anchor,
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
    if ctx.is_main:
        # Only now, with the data loaded and the model built: a mistake met on the way
        # leaves the run it was to replace as it was.
        if args.force and (cleared := clear_run(out)):
            log.info("--force: %s of the run in %s deleted", ", ".join(cleared), out)
        out.mkdir(parents=True, exist_ok=True)
    log.info(
        "training on %s in %s, %d process(es), %d batch worker thread(s)",
        device,
        opts.precision,
        ctx.world_size,
        opts.workers,
    )
    with stop_on_signals() as stop:
        status = trainer.fit(stop=stop)
    log.info("%s: %s after %d epochs, checkpoint %s", out, status, trainer.state.epoch, resume_from)
    if status != "stopped" and ctx.is_main:
        report = write_test_report(
            out, data.test, stride=opts.val_stride, weights=opts.loss_weights, device=device
        )
        if report is not None:
            test = report["test"]
            log.info(
                "test subjects %s (best.pt, epoch %s): %s -> %s",
                ",".join(report["test_subjects"] or []) or "-",
                report["epoch"],
                ", ".join(f"{k} {v:.4g}" for k, v in test.items() if isinstance(v, float)),
                out / "test.json",
            )
    return trainer


def _load_data(
    args: argparse.Namespace,
    ckpt: dict[str, Any] | None,
    cfg: ScottiConfig,
    opts: TrainOptions,
    ctx: DistContext,
) -> RunData:
    cache = args.cache or args.output.parent / ".session-cache"
    # Under torchrun rank 0 decodes first (filling the cache), then the others read it.
    if not ctx.is_main:
        distributed.barrier(ctx)
    sessions = load_sessions(args.sessions, cache)
    if ctx.is_main:
        distributed.barrier(ctx)
    if ckpt is not None and predates_validation_split(ckpt.get("training_data", {})):
        msg = f"{args.output} predates the validation split and cannot be resumed; train anew"
        raise TrainCliError(msg)
    data = prepare(
        sessions,
        window=cfg.window,
        allow_invalid=args.allow_invalid,
        test_subjects=args.test_subjects,
        test_fraction=args.test_fraction,
        val_subjects=args.val_subjects,
        val_fraction=args.val_fraction,
        seed=opts.seed,
    )
    if data.train.count(opts.stride) == 0:
        msg = f"no usable training windows of {cfg.window} frames in the given sessions"
        raise TrainCliError(msg)
    return data


def _benchmark(
    model: Scotti,
    data: RunData,
    opts: TrainOptions,
    args: argparse.Namespace,
    device: torch.device,
) -> None:
    """Print naive vs chunked (fp32, CPU) and fp32 vs bf16 (chunked, on ``device``)."""
    cfg = model.cfg
    plain = replace(
        opts,
        max_shift=0,
        max_crosstalk=0.0,
        sensor_transfer=0.0,
        tempo_stretch=0.0,
        tempo_extra=0.0,
    )
    rates = measure_throughput(model, data.train, plain, args.benchmark)
    print(
        f"E={cfg.embed_dim} T={cfg.window} batch={opts.batch} chunk={opts.chunk} "
        f"stride={opts.stride} threads={args.threads}: naive {rates['naive']:.1f} "
        f"windows/s, chunked {rates['chunked']:.1f} windows/s, x{rates['ratio']:.1f}"
    )
    rates = measure_precisions(model, data.train, plain, args.benchmark, device)
    print(
        f"precision on {device} (chunked, alternating): fp32 {rates['fp32']:.1f} windows/s, "
        f"bf16 {rates['bf16']:.1f} windows/s, bf16/fp32 x{rates['ratio']:.2f}"
    )


def _initial_checkpoint(path: Path) -> dict[str, Any]:
    """``--init``: a training checkpoint, or an exported graph's weights read back out of it."""
    if Path(path).suffix == ".onnx":
        ckpt = checkpoint_from_graph(path)
        worst = max(ckpt["parity"].values())
        log.info("--init: weights read back from %s (largest difference to it %.1e)", path, worst)
        return ckpt
    return load_checkpoint(path)


def _anchor(
    opts: TrainOptions, model: Scotti, init: dict[str, Any] | None, training_data: dict[str, Any]
) -> Anchor | None:
    """--keep-near's reference: the --init weights (read again from where the run first
    read them when it resumes, since the model then holds the checkpoint's)."""
    if opts.keep_near <= 0.0:
        return None
    if init is None:
        init = _initial_checkpoint(Path(training_data["init"]))
    reference = Scotti(model.cfg)
    load_initial_weights(reference, init["model"])
    log.info(
        "--keep-near %g (%s passes): pooled vectors held near %s",
        opts.keep_near, opts.keep_near_pass, training_data["init"],
    )  # fmt: skip
    return Anchor(reference, opts.keep_near, opts.keep_near_pass)


def _frozen_note(freeze: tuple[str, ...]) -> str:
    return f", {' and '.join(freeze)} frozen" if freeze else ""


def _warn_changed_options(before: dict[str, Any], now: dict[str, Any]) -> None:
    """Resuming with other batching or augmentation is allowed, but no longer exact."""
    ignore = {
        "epochs",
        "max_minutes",
        "save_minutes",
        "progress_bar",
        "workers",
        "patience",
        "min_delta",
    }
    changed = sorted(k for k in now if k not in ignore and k in before and before[k] != now[k])
    if changed:
        log.warning(
            "resuming with changed %s: the run will not match an uninterrupted one",
            ", ".join(changed),
        )


def _folder(training_data: dict[str, Any]) -> str:
    """The folder that holds a run's session files now (for the log)."""
    files = training_data.get("files") or []
    return os.path.commonpath([str(Path(f).parent) for f in files]) if files else "-"
