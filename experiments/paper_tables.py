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
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from common import (
    COMMANDS,
    DOCS,
    IMG,
    PARTITIONS,
    ROOT,
    RUNS,
    ExperimentError,
    load_partitions,
    read_json,
    run_parallel,
    scotti_command,
    shown,
    utc_now,
    write_json,
)
from tables_doc import write_evaluation_doc
from training import VARIANTS, RunSpec, export, measure, train


def evaluate_all(
    group: Path, jobs: list[tuple[str, list[Path], dict[str, Path]]], log: Path
) -> dict[str, list[dict[str, Any]]]:
    """Per partition, one replay of its held-out sessions feeding every variant's window;
    two partitions at a time (one core each); cached until a model changes."""
    results: dict[str, list[dict[str, Any]]] = {}
    todo = []
    for key, files, models in jobs:
        cmd = scotti_command(
            "eval",
            *files,
            *(a for m in models.values() for a in ("--model", m)),
            "--json",
            "--threads",
            "1",
        )
        out = group / "eval" / f"{key}.json"
        stamps = {name: path.stat().st_mtime for name, path in models.items()}
        if out.is_file() and read_json(out).get("stamps") == stamps:
            COMMANDS.append(shown(cmd))
            results[key] = list(read_json(out)["reports"])
        else:
            todo.append((key, models, cmd, out, stamps))
    for start in range(0, len(todo), 2):
        pair = todo[start : start + 2]
        began = time.monotonic()
        outs = run_parallel([cmd for _, _, cmd, _, _ in pair], log)
        seconds = time.monotonic() - began
        for (key, models, _, out, stamps), text in zip(pair, outs, strict=True):
            reports = json.loads(text)
            reports = reports if isinstance(reports, list) else [reports]
            for name, report in zip(models, reports, strict=True):
                report["variant"] = name
            write_json(out, {"stamps": stamps, "seconds": seconds, "reports": reports})
            results[key] = reports
    return results


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python experiments/paper_tables.py", description=__doc__)
    parser.add_argument(
        "--budget-minutes", type=float, required=True, help="training time of all 12 runs together"
    )
    parser.add_argument("--config", default="small", help="scotti train --config (preset or JSON)")
    parser.add_argument("--threads", type=int, default=2, help="torch threads per training run")
    parser.add_argument("--jobs", type=int, default=1, help="training runs side by side")
    parser.add_argument(
        "--clean-check",
        action="store_true",
        help="also score the multi-task models on the clean copies of the held-out sessions",
    )
    parser.add_argument("--doc", type=Path, default=DOCS / "evaluation.md")
    parser.add_argument("--img", type=Path, default=IMG, help="where the doc's figures go")
    parser.add_argument("--partitions", type=Path, default=PARTITIONS)
    parser.add_argument("--group", default="tables", help="runs/GROUP holds runs and results")
    args = parser.parse_args(argv)
    group = RUNS / args.group
    log = group / "log.txt"
    try:
        partitions = load_partitions(args.partitions)
        corpus = read_json(args.partitions)["corpus"]
        runs = [(p, v) for p in partitions for v in VARIANTS]
        share = 60.0 * args.budget_minutes / len(runs)
        rate_file = group / "throughput.json"
        if rate_file.is_file():
            rate, windows = read_json(rate_file)["rate"], read_json(rate_file)["windows"]
        else:
            spec = RunSpec(group / "bench", partitions[0], args.config, threads=args.threads)
            rate, windows = measure(spec, log)
            write_json(rate_file, {"rate": rate, "windows": windows, "config": args.config})
        print(f"training: {rate:.0f} windows/s measured, {share / 60:.1f} min per run", flush=True)
        specs = {
            (p.name, v): RunSpec(group / f"{p.name}-{v}", p, args.config, v, threads=args.threads)
            for p, v in runs
        }
        # --jobs 2 with --threads 1: two runs side by side, one core each.
        with ThreadPoolExecutor(max_workers=args.jobs) as pool:
            # Runs side by side slow each other down: on this machine two at once ran at about
            # half the rate one alone measured (the sweep's log), so plan with rate / jobs.
            futures = {
                k: pool.submit(train, s, share, rate / args.jobs, windows, log)
                for k, s in specs.items()
            }
            plans = {k: f.result() for k, f in futures.items()}
        jobs = []
        for partition in partitions:
            models = {
                v: export(
                    group / f"{partition.name}-{v}",
                    group / "models" / f"{partition.name}-{v}.onnx",
                    log,
                )
                for v in VARIANTS
            }
            jobs.append((partition.name, partition.test_files(), models))
            if args.clean_check:  # the same held-out subjects and motions without effects
                clean = [ROOT / corpus["clean"] / f.name for f in partition.test_files()]
                jobs.append((f"{partition.name}-clean", clean, {"multi": models["multi"]}))
        evaluated = evaluate_all(group, jobs, log)
        results = {p.name: evaluated[p.name] for p in partitions}
        clean_results = {
            p.name: evaluated[f"{p.name}-clean"][0]
            for p in partitions
            if f"{p.name}-clean" in evaluated
        }
        invocation = shown([sys.executable, "experiments/paper_tables.py", *(argv or sys.argv[1:])])
        write_evaluation_doc(
            args.doc,
            args.img,
            partitions=partitions,
            corpus=corpus,
            clean=clean_results,
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
