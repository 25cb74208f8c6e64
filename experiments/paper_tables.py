"""The paper's tables on our simulated corpus, in one command; writes docs/evaluation.md.

    nice -n 5 python experiments/paper_tables.py --budget-minutes 40

For each of the three subject-wise partitions (experiments/partitions.json):
train the multi-task model and its three single-task variants (same encoder,
same schedule, only the loss weights differ) on the 10 training subjects
within an equal share of the budget, export each to ONNX, and replay the 5
held-out subjects' session files through the daemon's streaming path with
``scotti eval``. Every figure is the mean over the three partitions ± the
sample standard deviation. Runs resume from their checkpoints: calling the
command again continues unfinished runs and rewrites the doc.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from common import (
    COMMANDS,
    DOCS,
    IMG,
    PARTITIONS,
    RUNS,
    ExperimentError,
    Partition,
    load_partitions,
    read_json,
    run,
    scotti_command,
    shown,
    utc_now,
    write_json,
)
from tables_doc import write_evaluation_doc
from training import VARIANTS, RunSpec, export, measure, train

GROUP = RUNS / "tables"


def evaluate(partition: Partition, models: dict[str, Path], log: Path) -> list[dict[str, Any]]:
    """One replay of the held-out sessions, every variant's window fed from it."""
    out = GROUP / "eval" / f"{partition.name}.json"
    stamps = {name: path.stat().st_mtime for name, path in models.items()}
    if out.is_file():
        cached = read_json(out)
        if cached.get("stamps") == stamps:
            return list(cached["reports"])
    cmd = scotti_command(
        "eval",
        *partition.test_files(),
        *(a for m in models.values() for a in ("--model", m)),
        "--json",
        "--threads",
        "1",
    )
    started = time.monotonic()
    reports = json.loads(run(cmd, log))
    seconds = time.monotonic() - started
    reports = reports if isinstance(reports, list) else [reports]
    for name, report in zip(models, reports, strict=True):
        report["variant"] = name
    write_json(out, {"stamps": stamps, "seconds": seconds, "reports": reports})
    return list(reports)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python experiments/paper_tables.py", description=__doc__)
    parser.add_argument(
        "--budget-minutes", type=float, required=True, help="training time of all 12 runs together"
    )
    parser.add_argument("--config", default="small", help="scotti train --config (preset or JSON)")
    parser.add_argument("--threads", type=int, default=2, help="torch threads per training run")
    parser.add_argument("--doc", type=Path, default=DOCS / "evaluation.md")
    args = parser.parse_args(argv)
    log = GROUP / "log.txt"
    try:
        partitions = load_partitions()
        runs = [(p, v) for p in partitions for v in VARIANTS]
        share = 60.0 * args.budget_minutes / len(runs)
        rate_file = GROUP / "throughput.json"
        if rate_file.is_file():
            rate, windows = read_json(rate_file)["rate"], read_json(rate_file)["windows"]
        else:
            spec = RunSpec(GROUP / "bench", partitions[0], args.config, threads=args.threads)
            rate, windows = measure(spec, log)
            write_json(rate_file, {"rate": rate, "windows": windows, "config": args.config})
        print(f"training: {rate:.0f} windows/s measured, {share / 60:.1f} min per run", flush=True)
        plans: dict[tuple[str, str], dict[str, Any]] = {}
        for partition, variant in runs:
            spec = RunSpec(
                GROUP / f"{partition.name}-{variant}",
                partition,
                args.config,
                variant,
                threads=args.threads,
            )
            plans[partition.name, variant] = train(spec, share, rate, windows, log)
        results: dict[str, list[dict[str, Any]]] = {}
        for partition in partitions:
            models = {
                v: export(
                    GROUP / f"{partition.name}-{v}",
                    GROUP / "models" / f"{partition.name}-{v}.onnx",
                    log,
                )
                for v in VARIANTS
            }
            results[partition.name] = evaluate(partition, models, log)
        invocation = shown([sys.executable, "experiments/paper_tables.py", *(argv or sys.argv[1:])])
        write_evaluation_doc(
            args.doc,
            IMG,
            partitions=partitions,
            corpus=read_json(PARTITIONS)["corpus"],
            plans=plans,
            results=results,
            invocation=invocation,
            commands=COMMANDS,
            written=utc_now(),
        )
        print(f"wrote {args.doc}")
    except ExperimentError as exc:
        print(f"paper_tables: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
