"""``scotti train``'s command line: the options, grouped as ``--help`` shows them."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from scotti.export.anchor import PASSES
from scotti.export.devices import DEVICES, PRECISIONS
from scotti.export.finetune import FREEZE_GROUPS
from scotti.export.model import ARCHES
from scotti.export.run_dir import RUN_FILES
from scotti.export.train_options import NORM_STATISTICS, TrainOptions
from scotti.export.validation import VAL_FRACTION

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


def add_arguments(parser: argparse.ArgumentParser) -> None:
    d = TrainOptions()
    parser.add_argument("sessions", nargs="+", type=Path, help="session files or directories")
    parser.add_argument(
        "-o",
        "--output",
        type=Path,
        required=True,
        help="run directory; one that holds a run (" + ", ".join(RUN_FILES) + ") is refused, "
        "unless --resume or --force",
    )
    parser.add_argument(
        "--config",
        default=None,
        help="model size: "
        + "|".join(CONFIG_PRESETS)
        + ", a JSON object or a .json file"
        + " (default small; with --init, the checkpoint's)",
    )
    parser.add_argument(
        "--arch",
        choices=ARCHES,
        default=None,
        help="paper: the paper's encoder (absolute positions, full attention); streaming: "
        "relative positions, causal, a key/value cache, ~2 tokens a step instead of T+1 "
        "(docs/streaming-native.md). Default: the --config's (paper)",
    )
    parser.add_argument(
        "--init",
        type=Path,
        default=None,
        metavar="CHECKPOINT",
        help="start from this checkpoint's weights, or an exported graph's (NAME.onnx, e.g. "
        "models/scotti-default.onnx): fine-tuning, fresh optimiser and schedule",
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
    parser.add_argument(
        "--max-crosstalk",
        type=float,
        default=d.max_crosstalk,
        help="augmentation: add up to this row/column crosstalk per chunk and foot "
        "(0 = off; the simulator's realistic insoles have 0.005-0.03)",
    )
    parser.add_argument(
        "--sensor-transfer",
        type=float,
        default=d.sensor_transfer,
        metavar="P",
        help="augmentation: render this share of chunks as an import from a drawn foreign "
        "insole would bring them in (another grid or discrete cells, curve, gain and rate; "
        "export/sensor_transfer.py; 0 = off)",
    )
    parser.add_argument(
        "--tempo-stretch",
        type=float,
        default=d.tempo_stretch,
        metavar="P",
        help="augmentation: play this share of chunks slower or faster, at a tempo drawn from "
        "--tempo-range (export/tempo.py; jumps never; 0 = off)",
    )
    parser.add_argument(
        "--tempo-range",
        default=",".join(f"{t:g}" for t in d.tempo_range),
        metavar="LO,HI",
        help="the tempi --tempo-stretch draws between, log-uniform (0.8: 20 %% slower)",
    )
    parser.add_argument(
        "--tempo-extra",
        type=float,
        default=d.tempo_extra,
        metavar="P",
        help="augmentation: a further share of chunks (beside --tempo-stretch's) at a tempo "
        "drawn from --tempo-extra-range, e.g. the extremes a scene may set (0 = off)",
    )
    parser.add_argument(
        "--tempo-extra-range",
        default=",".join(f"{t:g}" for t in d.tempo_extra_range),
        metavar="LO,HI",
        help="the tempi --tempo-extra draws between, log-uniform",
    )
    parser.add_argument(
        "--ema",
        type=float,
        default=d.ema,
        metavar="DECAY",
        help="validate, pick best.pt and export an exponential moving average of the weights, "
        "updated every step with this decay (e.g. 0.999; 0 = off)",
    )
    parser.add_argument(
        "--keep-near",
        type=float,
        default=d.keep_near,
        metavar="WEIGHT",
        help="with --init: add WEIGHT x the relative squared distance of the pooled vectors of "
        "each batch's first chunk (a dropout-free pass) to what the --init weights give for "
        "them, so a fine-tune keeps the representation the unfamiliar flag is calibrated on "
        "(export/anchor.py; 0 = off)",
    )
    parser.add_argument(
        "--norm-statistics",
        choices=NORM_STATISTICS,
        default=None,
        help="the frame CNN's batch norm while training: 'batch' normalises by each batch "
        "(its running statistics follow), 'kept' by the statistics it has, as at inference "
        "(default: kept for --init weights whose statistics an exported graph folded "
        "away, read back from it or fine-tuned from it so; a resumed run's own; batch "
        "otherwise)",
    )
    parser.add_argument(
        "--keep-near-pass",
        choices=PASSES,
        default=d.keep_near_pass,
        help="what --keep-near compares: 'eval', a dropout-free pass of the first chunk; "
        "'matched', the training pass of every window against the --init weights' replay of "
        "it with the same dropout masks and batch statistics (0 until the weights move)",
    )
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
    parser.add_argument(
        "--save-minutes",
        type=float,
        default=d.save_minutes,
        metavar="N",
        help="also write last.pt every N minutes of training, so a run killed without "
        "warning loses at most that much (0 = only at epoch ends and stops; SIGTERM or "
        "Ctrl-C always finish the step and write last.pt)",
    )
    parser.add_argument(
        "--test-subjects", nargs="*", default=None, help="subjects held out, never trained on"
    )
    parser.add_argument("--test-fraction", type=float, default=0.2)
    again = parser.add_mutually_exclusive_group()
    again.add_argument(
        "--resume",
        action="store_true",
        help="continue from OUTPUT/last.pt (none there and no run: a new run)",
    )
    again.add_argument(
        "--force",
        action="store_true",
        help="start over in a run directory that holds a run: its "
        + ", ".join(RUN_FILES)
        + " are deleted before the new run writes (other files stay)",
    )
    parser.add_argument("--cache", type=Path, default=None, help="decoded-session cache dir")
    parser.add_argument("--allow-invalid", action="store_true", help="keep windows with gaps")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument(
        "--benchmark",
        type=int,
        default=0,
        metavar="STEPS",
        help="only measure training windows/s over STEPS batches: naive vs chunked, fp32 vs bf16",
    )
    add_validation_arguments(parser)
    add_device_arguments(parser)


def add_validation_arguments(parser: argparse.ArgumentParser) -> None:
    d = TrainOptions()
    group = parser.add_argument_group(
        "validation and early stopping",
        "validation is drawn from the training subjects (never the test subjects); it picks "
        "best.pt and stops the run on a plateau",
    )
    group.add_argument(
        "--val-subjects", nargs="*", default=None, help="validation subjects (default: drawn)"
    )
    group.add_argument(
        "--val-fraction",
        type=float,
        default=VAL_FRACTION,
        help="share of the training subjects drawn for validation, at least one (one subject: "
        "the last part of each session)",
    )
    group.add_argument(
        "--watch",
        nargs="+",
        type=Path,
        default=None,
        metavar="SESSION",
        help="session files or directories scored after every epoch and never trained on "
        "(the shipped scenes, people unlike the corpus): accuracy, recall per action and APP "
        "per file in the log and history.jsonl; they never pick best.pt",
    )
    group.add_argument(
        "--patience",
        type=int,
        default=d.patience,
        help="stop after this many epochs without a validation improvement (0 = never)",
    )
    group.add_argument(
        "--min-delta",
        type=float,
        default=d.min_delta,
        help="the smallest fall of the validation loss that counts as an improvement",
    )


def add_device_arguments(parser: argparse.ArgumentParser) -> None:
    d = TrainOptions()
    group = parser.add_argument_group(
        "device and distributed",
        "several processes: torchrun --nproc-per-node N -m scotti.cli.main train ... "
        "(gloo on CPU, nccl on CUDA; RANK, WORLD_SIZE, LOCAL_RANK from torchrun)",
    )
    group.add_argument(
        "--device", choices=DEVICES, default="auto", help="auto: cuda if torch sees a GPU"
    )
    group.add_argument(
        "--precision",
        choices=PRECISIONS,
        default=d.precision,
        help="bf16: autocast of the forward pass (CPU and CUDA)",
    )
    group.add_argument(
        "--workers",
        type=int,
        default=d.workers,
        help="threads building batches ahead of the step (0 = in the training loop)",
    )
