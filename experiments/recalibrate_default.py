"""The shipped model's weights with its unfamiliar flag fitted again, as export fits it now.

    python experiments/recalibrate_default.py --sessions data/corpus21 --cache-dir data/cache21 \\
        -o runs/default-recalibrated [--model models/scotti-default.onnx] [--ood-windows N]

A candidate's flag is fitted by today's ``scotti export --calibrate`` (its
default number of windows, clean copies left out, as scripts/train_wide.sh
calibrates); the shipped model's was fitted when it shipped, on 4,000 windows
a side. Line 2 of the rule (experiments/wide_rule.py) compares what the two
publish, so both flags must be fitted the same way: this rebuilds a training
checkpoint from the shipped graphs (export/graph_weights.py, checked against
them), names in it the training and held-out people the shipped card's
calibration used, and exports it with the flag calibrated again on the same
people's sessions under ``--sessions``. The progress map is not refitted
(``--progress-windows 0``): the graphs keep the head's progress as it is,
which no line of the rule reads. Writes OUTPUT/base.pt and
OUTPUT/models/scotti-ship.onnx (with its window graph and card); pass that
to ``wide_rule.py --shipped``. About 5 minutes and 10 GiB on 2 cores with
data/corpus21 (export decodes every session it is given).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import ROOT, ExperimentError, run, scotti_command
from flag_operating_points import calibration_files


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--model", type=Path, default=ROOT / "models" / "scotti-default.onnx")
    parser.add_argument("--sessions", type=Path, required=True)
    parser.add_argument("--cache-dir", type=Path)
    parser.add_argument("-o", "--output", type=Path, required=True)
    parser.add_argument("--ood-windows", type=int, help="export's --ood-windows (its default)")
    args = parser.parse_args(argv)
    try:
        return recalibrate(args)
    except ExperimentError as e:
        print(f"recalibrate_default: {e}", file=sys.stderr)
        return 2


def recalibrate(args: argparse.Namespace) -> int:
    from scotti.export.checkpoint import save_checkpoint
    from scotti.export.graph_weights import checkpoint_from_graph

    card_path = args.model.with_name(args.model.stem + ".card.json")
    ood = json.loads(card_path.read_text()).get("ood") or {}
    if not ood.get("train_subjects") or not ood.get("held_out_subjects"):
        msg = f"{card_path} names no calibration people (ood.train_subjects, held_out_subjects)"
        raise ExperimentError(msg)
    ckpt = checkpoint_from_graph(args.model)
    ckpt["training_data"] = {
        "split": {
            "train_subjects": list(ood["train_subjects"]),
            "validation_subjects": list(ood["held_out_subjects"]),
        },
        "init": str(args.model),
    }
    args.output.mkdir(parents=True, exist_ok=True)
    base = args.output / "base.pt"
    save_checkpoint(ckpt, base)
    files = calibration_files(args.sessions)
    out = args.output / "models" / "scotti-ship.onnx"
    command = ["export", base, "-o", out, "--calibrate", *files, "--progress-windows", "0"]
    command += ["--force", "--ood-percentile", str(ood.get("threshold_percentile", 99.0))]
    if args.cache_dir is not None:
        command += ["--cache-dir", args.cache_dir]
    if args.ood_windows is not None:
        command += ["--ood-windows", str(args.ood_windows)]
    run(scotti_command(*command), args.output / "export.log")
    print(f"recalibrate_default: {out} (the weights of {args.model}, the flag fitted again)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
