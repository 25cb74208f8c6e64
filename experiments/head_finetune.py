"""Fine-tune one head of a shipped model on a partition, everything else frozen, then score it.

    nice -n 5 python experiments/head_finetune.py p1 --graph models/scotti-default.onnx
    python experiments/head_finetune.py p1 --graph ... --max-minutes 30   # goes on from there

Why: a multi-task model trades its tasks against each other through the
shared trunk. Raising the progress loss's weight for a whole-model fine-tune
bought progress but gave back standing recall (export/TRAINING.md). With the
CNN, the encoder and the other heads frozen (``scotti train --freeze``), the
pooled representation, pose, action logits and the unfamiliar score stay bit
for bit what the base model computes; only the head's output moves.

Steps, into runs/GROUP-PARTITION-HEAD-head:
1. experiments/checkpoint_from_onnx.py: the base graph's weights as base.pt
   (checked against the graph);
2. ``scotti train --init base.pt --freeze`` (all but the head) with that
   head's loss alone, on the partition's training subjects plus the 18 extra
   people, validated on the subjects experiments/partition_runs.py uses, with
   the shipped recipe's crosstalk augmentation; a run that ``--max-minutes``
   stopped resumes from last.pt on the next call;
3. ``scotti export --calibrate``, ``scotti calibrate`` on the validation
   subjects, and ``scotti eval --json`` of the new model and the base graph on
   the partition's held-out subjects in one replay (eval/test.json: the new
   model first).

The held-out subjects are never given to ``scotti train`` or to the calibrations.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from common import ROOT, RUNS, ExperimentError, load_partitions, run, scotti_command
from partition_runs import CORPUS, PartitionRun, export_command

HERE = Path(__file__).resolve().parent
HEADS = ("pose", "action", "progress")
FROZEN_BESIDE = {h: ["cnn", "encoder", *(f"{o}_head" for o in HEADS if o != h)] for h in HEADS}
LOSS = {"pose": "1,0,0", "action": "0,1,0", "progress": "0,0,1"}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python experiments/head_finetune.py",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("partition", help="p1, p2 or p3 (experiments/partitions.json)")
    parser.add_argument("--graph", type=Path, required=True, help="the base model's NAME.onnx")
    parser.add_argument("--head", choices=HEADS, default="progress")
    parser.add_argument("--group", default="v9")
    parser.add_argument("--corpus", type=Path, default=CORPUS)
    parser.add_argument("--cache", default="data/cache7")
    parser.add_argument("--epochs", type=int, default=4)
    parser.add_argument("--patience", type=int, default=2)
    parser.add_argument("--stride", type=int, default=16)
    parser.add_argument("--lr", type=float, default=1e-3)
    parser.add_argument("--max-crosstalk", type=float, default=0.03)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--max-minutes", type=float, default=60)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        known = {p.name: p for p in load_partitions()}
        if args.partition not in known:
            raise ExperimentError(f"unknown partition {args.partition}: {', '.join(known)}")
        part = known[args.partition]
        run_dir = RUNS / f"{args.group}-{args.partition}-{args.head}-head"
        job = PartitionRun(args.partition, part.train, part.test, run_dir)
        run_dir.mkdir(parents=True, exist_ok=True)
        log = run_dir / "run.log"
        base = run_dir / "base.pt"
        if not base.is_file():
            check = job.files(args.corpus, job.validation[:1])[0]
            rebuild = [sys.executable, str(HERE / "checkpoint_from_onnx.py"), str(args.graph)]
            run([*rebuild, "-o", str(base), "--check", str(check)], log)
        if not job.finished(args.epochs):
            resume = ["--resume"] if (run_dir / "last.pt").is_file() else []
            train = scotti_command(
                "train", *job.files(args.corpus), "-o", run_dir, "--init", base,
                "--freeze", *FROZEN_BESIDE[args.head], "--loss-weights", LOSS[args.head],
                "--val-subjects", *job.validation, "--test-fraction", "0",
                "--epochs", str(args.epochs), "--patience", str(args.patience),
                "--stride", str(args.stride), "--val-stride", "8", "--lr", str(args.lr),
                "--threads", str(args.threads), "--max-minutes", str(args.max_minutes),
                "--cache", args.cache, "--max-crosstalk", str(args.max_crosstalk), "--no-progress",
                *resume,
            )  # fmt: skip
            run(train, log)
            if not job.finished(args.epochs):
                print(f"{run_dir}: training goes on at the next call (--max-minutes ran out)")
                return 0
        model = run_dir / "models" / "scotti-ship.onnx"
        report = run_dir / "eval" / "test.json"
        if not report.is_file():
            run(scotti_command(*export_command(job, args.corpus, args.cache)), log)
            run(scotti_command("calibrate", model, *job.files(args.corpus, job.validation)), log)
            models = ["--model", model, "--model", args.graph]
            test = job.files(args.corpus, job.test)
            out = run(scotti_command("eval", *test, *models, "--json"), log)
            report.parent.mkdir(parents=True, exist_ok=True)
            report.write_text(out)
        name = args.partition
        print(f"{name}={report.relative_to(ROOT)} --run {name}={run_dir.relative_to(ROOT)}")
    except ExperimentError as exc:
        print(f"head_finetune: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
