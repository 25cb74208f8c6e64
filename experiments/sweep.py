"""What accuracy costs in time, in one command; writes docs/accuracy-vs-latency.md.

    nice -n 5 python experiments/sweep.py --budget-minutes 20 [--ship]

Over model width E (128, 256, 512), transformer depth, window T (20, 40) and
precision (fp32 vs int8 MatMul/Gemm; int8 with Conv too, for latency): each
config is trained on partition p1's training subjects within an equal share
of the budget, exported (fp32 + int8), and scored with ``scotti eval`` on
p1's held-out subjects (all models fed from one replay). Latency is the
streaming step as the daemon calls it, batch 1, one and two threads, against
recomputing the whole window; FLOPs come from the ONNX graphs. ``--ship``
then ships the most accurate model whose streaming step stays under 10 ms
p99 on one thread as models/scotti-default.*. Resumable: a second call
continues unfinished training and reuses finished results.
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
    run,
    run_parallel,
    scotti_command,
    shown,
    utc_now,
    write_json,
)
from measure import conv_int8, graph_flops
from scotti.models.runtime import window_graph_for
from sweep_doc import choose_default, rows_of, write_sweep_doc
from training import RunSpec, export, measure, train

HERE = Path(__file__).resolve().parent
LIMIT_P99_MS = 10.0
CONTRACT_WINDOW = 40  # the daemon's T (models.contract.WINDOW)
# Adam's step size by width: short budgets want it brisk, wide transformers want it gentler.
LEARNING_RATE = {128: 1e-3, 256: 5e-4, 512: 3e-4}

# name -> ScottiConfig fields (the rest from the paper's defaults: conv 16/32, dropout 0.1).
CONFIGS: dict[str, dict[str, Any]] = {
    "E128-L2-T40": {"embed_dim": 128, "layers": 2, "heads": 4, "head_hidden": 128},
    "E128-L2-T20": {"embed_dim": 128, "layers": 2, "heads": 4, "head_hidden": 128, "window": 20},
    "E256-L2-T40": {"embed_dim": 256, "layers": 2, "heads": 4, "head_hidden": 256},
    "E256-L4-T40": {"embed_dim": 256, "layers": 4, "heads": 8, "head_hidden": 256},
    "E512-L4-T40": {"embed_dim": 512, "layers": 4, "heads": 8, "head_hidden": 256},
}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python experiments/sweep.py", description=__doc__)
    parser.add_argument("--budget-minutes", type=float, required=True, help="all training")
    parser.add_argument("--configs", nargs="*", default=list(CONFIGS), choices=list(CONFIGS))
    parser.add_argument("--partition", default="p1")
    parser.add_argument(
        "--eval-subjects", type=int, default=2, help="how many of the held-out subjects to score"
    )
    parser.add_argument("--threads", type=int, default=2, help="torch threads for training")
    parser.add_argument("--jobs", type=int, default=1, help="training runs side by side")
    parser.add_argument("--latency-steps", type=int, default=400)
    parser.add_argument("--partitions", type=Path, default=PARTITIONS)
    parser.add_argument("--group", default="sweep")
    parser.add_argument("--doc", type=Path, default=DOCS / "accuracy-vs-latency.md")
    parser.add_argument("--img", type=Path, default=IMG)
    parser.add_argument("--ship", action="store_true", help="ship the chosen default model")
    args = parser.parse_args(argv)
    group = RUNS / args.group
    log = group / "log.txt"
    try:
        partition = next(
            (p for p in load_partitions(args.partitions) if p.name == args.partition), None
        )
        if partition is None:
            msg = f"no partition {args.partition} in {args.partitions}"
            raise ExperimentError(msg)
        share = 60.0 * args.budget_minutes / len(args.configs)
        rates = (
            read_json(group / "throughput.json") if (group / "throughput.json").is_file() else {}
        )
        specs = {
            name: RunSpec(
                group / name,
                partition,
                json.dumps(CONFIGS[name]),
                threads=args.threads,
                lr=LEARNING_RATE[CONFIGS[name]["embed_dim"]],
            )
            for name in args.configs
        }
        for name, spec in specs.items():
            if name not in rates:
                bench = RunSpec(group / "bench", partition, spec.config, threads=args.threads)
                rate, windows = measure(bench, log)
                rates[name] = {"rate": rate, "windows": windows}
                write_json(group / "throughput.json", rates)
        # --jobs 2 with --threads 1: two configs side by side, one core each.
        with ThreadPoolExecutor(max_workers=args.jobs) as pool:
            futures = {
                n: pool.submit(train, s, share, rates[n]["rate"], rates[n]["windows"], log)
                for n, s in specs.items()
            }
            plans = {n: f.result() for n, f in futures.items()}
        models = {
            n: export(group / n, group / "models" / f"{n}.onnx", log, int8=True)
            for n in specs
            if (group / n / "last.pt").is_file()  # a run that failed before its first checkpoint
        }
        # int8 with the Conv layers quantized too: measured for latency only.
        conv = {}
        for name in ("E128-L2-T40", "E512-L4-T40"):
            if name in models:
                src = models[name]
                conv_int8(window_graph_for(src), group / "models" / f"{name}.int8conv.window.onnx")
                conv[name] = conv_int8(src, group / "models" / f"{name}.int8conv.onnx")
        frames_per_window = {n: int(CONFIGS[n].get("window", CONTRACT_WINDOW)) for n in models}
        files = partition.test_files()[: args.eval_subjects]
        evaluated = evaluate(group, files, models, frames_per_window, log)
        steps = [p for m in models.values() for p in (m, _int8(m))] + list(conv.values())
        latency = measure_latency(group, steps, args.latency_steps, log)
        rows = rows_of(models, conv, plans, evaluated, latency)
        choice = choose_default(rows, LIMIT_P99_MS)
        invocation = shown([sys.executable, "experiments/sweep.py", *(argv or sys.argv[1:])])
        write_sweep_doc(
            args.doc,
            args.img,
            rows=rows,
            choice=choice,
            limit_ms=LIMIT_P99_MS,
            partition=partition,
            eval_subjects=args.eval_subjects,
            invocation=invocation,
            commands=list(
                dict.fromkeys(COMMANDS + sorted({c for p in plans.values() for c in p["commands"]}))
            ),
            written=utc_now(),
        )
        print(f"wrote {args.doc}; default: {choice['label'] if choice else 'none'}")
        if args.ship and choice is not None:
            ship(choice, group, partition, plans, log)
    except ExperimentError as exc:
        print(f"sweep: {exc}", file=sys.stderr)
        return 1
    return 0


def _int8(step: Path) -> Path:
    return step.with_name(step.name.removesuffix(".onnx") + ".int8.onnx")


def balanced(steps: list[Path]) -> list[list[Path]]:
    """Two groups of models of about equal cost (FLOPs per step; int8 counted at 40 %), so
    that the two eval processes, one per core, end together."""
    cost = {p: graph_flops(p) * (0.4 if ".int8." in p.name else 1.0) for p in steps}
    bins: list[list[Path]] = [[], []]
    load = [0.0, 0.0]
    for p in sorted(steps, key=cost.__getitem__, reverse=True):
        i = 0 if load[0] <= load[1] else 1
        bins[i].append(p)
        load[i] += cost[p]
    return [b for b in bins if b]


def evaluate(
    group: Path, files: list[Path], models: dict[str, Path], windows: dict[str, int], log: Path
) -> dict[str, Any]:
    """One replay of the held-out sessions for every fp32 and int8 model (cached by mtime)."""
    out = group / "eval.json"
    steps = [p for m in models.values() for p in (m, _int8(m))]
    stamps = {str(p): p.stat().st_mtime for p in steps} | {"files": [str(f) for f in files]}
    if out.is_file() and read_json(out).get("stamps") == stamps:
        COMMANDS.extend(read_json(out).get("commands", []))
        return dict(read_json(out)["reports"])
    first = len(COMMANDS)
    started = time.monotonic()
    reports = []
    for window in sorted({windows[name] for name in models}, reverse=True):
        group_models = [m for name, m in models.items() if windows[name] == window]
        cmds = []
        for half in balanced([p for m in group_models for p in (m, _int8(m))]):
            args = ["eval", *files, *(a for p in half for a in ("--model", p))]
            args += ["--json", "--threads", "1"]
            if window == CONTRACT_WINDOW:
                cmds.append(scotti_command(*args))
            else:  # outside the daemon's contract: see any_window.py
                cmds.append(
                    [sys.executable, str(HERE / "any_window.py"), str(window), *map(str, args)]
                )
        reports += [r for out in run_parallel(cmds, log) for r in _as_list(json.loads(out))]
    by_path = {str(Path(r["model"]["path"]).resolve()): r for r in reports}
    result = {str(p): by_path[str(p.resolve())] for p in steps}
    seconds = time.monotonic() - started
    made = COMMANDS[first:]
    write_json(out, {"stamps": stamps, "seconds": seconds, "commands": made, "reports": result})
    return result


def _as_list(value: Any) -> list[Any]:
    return value if isinstance(value, list) else [value]


def measure_latency(group: Path, steps: list[Path], n: int, log: Path) -> dict[str, Any]:
    """experiments/measure.py over every step graph (cached by mtime: delete to re-measure)."""
    out = group / "latency.json"
    stamps = {str(p): p.stat().st_mtime for p in steps}
    cmd = [sys.executable, str(HERE / "measure.py"), *map(str, steps), "--steps", str(n)]
    if out.is_file() and read_json(out).get("stamps") == stamps:
        COMMANDS.append(shown(cmd))
        return dict(read_json(out)["models"])
    measured = json.loads(run(cmd, log))
    write_json(out, {"stamps": stamps, "measured_utc": utc_now(), "models": measured})
    return dict(measured)


def ship(
    choice: dict[str, Any], group: Path, partition: Any, plans: dict[str, Any], log: Path
) -> None:
    name = choice["config"]
    plan = plans[name]
    data = (
        f"Simulated corpus (experiments/partitions.json): partition {partition.name}'s "
        f"{len(partition.train)} training subjects ({', '.join(partition.train)}), all 8 actions, "
        "with the realistic sensor and transport effects. Config "
        f"{name}; {plan['trained_s'] / 60:.1f} min of training on this shared 2-core CPU "
        f"({plan.get('epochs_done', 0)}/{plan['epochs']} epochs at stride {plan['stride']}, "
        f"lr {LEARNING_RATE[CONFIGS[name]['embed_dim']]:g}); undertrained. Chosen by "
        "`python experiments/sweep.py` as the most accurate "
        "model whose streaming step stays under 10 ms p99 on one thread."
    )
    evaluated = group / "eval.json"
    report = read_json(evaluated)["reports"][choice["path"]]
    single = group / "default-eval.json"
    write_json(single, report)
    cmd = [
        sys.executable,
        str(HERE / "ship_default.py"),
        str(group / "models" / f"{name}.onnx"),
        *(["--int8"] if choice["precision"] == "int8" else []),
        "--eval",
        str(single),
        "--eval-command",
        next(
            (c for c in COMMANDS if " eval " in c and Path(choice["path"]).name + " " in c + " "),
            "scotti eval (see docs/accuracy-vs-latency.md)",
        ),
        "--from",
        str((group / name / "last.pt").relative_to(ROOT)),
        "--data",
        data,
        "--note",
        "Metrics: one training run, scored on the held-out subjects listed; the "
        "spread is over those subjects (per-subject figures), not over partitions. "
        "docs/evaluation.md has three-partition figures for the `small` config (E=128, "
        "2 layers, T=40).",
    ]
    run(cmd, log)


if __name__ == "__main__":
    raise SystemExit(main())
