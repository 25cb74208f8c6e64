"""What accuracy costs in time, in one command; writes docs/accuracy-vs-latency.md.

    nice -n 5 python experiments/sweep.py --budget-minutes 60 --jobs 2 --threads 1 [--ship]

Over model width E (128, 256, 512), transformer depth, window T (20, 40) and
precision (fp32 vs int8 MatMul/Gemm; int8 with Conv too, for latency): each
config is trained on each of the three subject-wise partitions' 10 training
subjects (experiments/partitions.json) within an equal share of the budget,
exported (fp32 + int8), and scored with ``scotti eval --every K`` on that
partition's 5 held-out subjects (every model of a partition fed from one
replay). Every accuracy figure is the mean over the partitions and its sample
SD. Latency is the streaming step as the daemon calls it, batch 1, one and
two threads, against recomputing the whole window, measured once per config
and precision on the first partition's model (weights do not change it);
FLOPs come from the ONNX graphs. ``--ship`` then ships the first partition's
model of the most accurate config whose streaming step stays under 10 ms p99
on one thread as models/scotti-default.* (through scripts/ship_default.py).
Resumable: a second call continues unfinished training and reuses finished
results.
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
    Partition,
    load_partitions,
    read_json,
    run,
    run_parallel,
    scoring,
    scotti_command,
    shown,
    utc_now,
    write_json,
)
from configs import CONFIGS, CONTRACT_WINDOW, LEARNING_RATE, SWEEP_CONFIGS
from measure import conv_int8, graph_flops
from scotti.models.contract import NUM_ACTIONS
from scotti.models.runtime import window_graph_for
from sweep_doc import choose_default, rows_of, write_sweep_doc
from training import RunSpec, export, measure, train

HERE = Path(__file__).resolve().parent
LIMIT_P99_MS = 10.0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python experiments/sweep.py", description=__doc__)
    parser.add_argument(
        "--budget-minutes", type=float, required=True, help="all training runs together"
    )
    parser.add_argument("--configs", nargs="*", default=list(SWEEP_CONFIGS), choices=list(CONFIGS))
    parser.add_argument(
        "--partitions-used",
        nargs="*",
        default=None,
        metavar="NAME",
        help="partitions to train and score on (default: all in --partitions); the first "
        "one's models are timed and shipped",
    )
    parser.add_argument(
        "--eval-every",
        type=int,
        default=8,
        metavar="K",
        help="scotti eval --every K: score every K-th prediction time (window graph)",
    )
    parser.add_argument("--threads", type=int, default=2, help="torch threads for training")
    parser.add_argument("--jobs", type=int, default=1, help="training runs side by side")
    parser.add_argument("--latency-steps", type=int, default=400)
    parser.add_argument("--partitions", type=Path, default=PARTITIONS)
    parser.add_argument("--group", default="sweep")
    parser.add_argument("--doc", type=Path, default=DOCS / "accuracy-vs-latency.md")
    parser.add_argument("--img", type=Path, default=IMG)
    parser.add_argument("--ship", action="store_true", help="ship the chosen default model")
    parser.add_argument(
        "--ship-to", type=Path, default=ROOT / "models", help="where --ship puts it (models/)"
    )
    args = parser.parse_args(argv)
    group = RUNS / args.group
    log = group / "log.txt"
    try:
        if args.eval_every < 1:
            msg = f"--eval-every must be at least 1, got {args.eval_every}"
            raise ExperimentError(msg)
        partitions = used_partitions(args.partitions, args.partitions_used)
        lead = partitions[0]  # its models are timed and shipped
        share = 60.0 * args.budget_minutes / (len(args.configs) * len(partitions))
        print(
            f"training: {len(args.configs)} configs x {len(partitions)} partitions, "
            f"{share / 60:.1f} min per run",
            flush=True,
        )
        rates = throughputs(group, args.configs, lead, args.threads, log)
        specs = {
            (name, p.name): RunSpec(
                group / name / p.name,
                p,
                json.dumps(CONFIGS[name]),
                threads=args.threads,
                lr=LEARNING_RATE[CONFIGS[name]["embed_dim"]],
            )
            for name in args.configs
            for p in partitions
        }
        # --jobs 2 with --threads 1: two runs side by side, one core each. Runs side by side
        # slow each other down (about half the rate one alone measured, paper_tables' log),
        # so they are planned with rate / jobs.
        with ThreadPoolExecutor(max_workers=args.jobs) as pool:
            futures = {
                (name, part): pool.submit(
                    train, s, share, rates[name]["rate"] / args.jobs, rates[name]["windows"], log
                )
                for (name, part), s in specs.items()
            }
            done = {key: f.result() for key, f in futures.items()}
        plans: dict[str, dict[str, Any]] = {}
        for (name, part), state in done.items():
            plans.setdefault(name, {})[part] = state
        # config -> partition -> fp32 step graph; a run that failed before its first
        # checkpoint has none.
        models: dict[str, dict[str, Path]] = {}
        for (name, part), spec in specs.items():
            if (spec.run_dir / "last.pt").is_file():
                onnx = group / "models" / f"{name}-{part}.onnx"
                models.setdefault(name, {})[part] = export(spec.run_dir, onnx, log, int8=True)
        timed = {name: by[lead.name] for name, by in models.items() if lead.name in by}
        # int8 with the Conv layers quantized too: measured for latency only.
        conv = {}
        for name in ("E128-L2-T40", "E512-L4-T40"):
            if name in timed:
                src = timed[name]
                stem = src.name.removesuffix(".onnx")
                conv_int8(window_graph_for(src), src.with_name(f"{stem}.int8conv.window.onnx"))
                conv[name] = conv_int8(src, src.with_name(f"{stem}.int8conv.onnx"))
        frames_per_window = {n: int(CONFIGS[n].get("window", CONTRACT_WINDOW)) for n in models}
        evaluated: dict[str, Any] = {}
        for p in partitions:
            of_p = {n: by[p.name] for n, by in models.items() if p.name in by}
            evaluated |= evaluate(group, p, of_p, frames_per_window, args.eval_every, log)
        steps = [q for m in timed.values() for q in (m, _int8(m))] + list(conv.values())
        latency = measure_latency(group, steps, args.latency_steps, log)
        rows = rows_of(models, timed, conv, plans, evaluated, latency)
        choice = choose_default(rows, LIMIT_P99_MS)
        invocation = shown([sys.executable, "experiments/sweep.py", *(argv or sys.argv[1:])])
        trained = sorted({c for by in plans.values() for p in by.values() for c in p["commands"]})
        write_sweep_doc(
            args.doc,
            args.img,
            rows=rows,
            choice=choice,
            limit_ms=LIMIT_P99_MS,
            partitions=partitions,
            every=args.eval_every,
            share_min=share / 60,
            invocation=invocation,
            commands=list(dict.fromkeys(COMMANDS + trained)),
            written=utc_now(),
        )
        print(f"wrote {args.doc}; default: {choice['label'] if choice else 'none'}")
        if args.ship and choice is not None:
            ship(choice, group, partitions, plans[choice["config"]], evaluated, args.ship_to, log)
    except ExperimentError as exc:
        print(f"sweep: {exc}", file=sys.stderr)
        return 1
    return 0


def used_partitions(path: Path, names: list[str] | None) -> list[Partition]:
    """The partitions named (in that order), or all of them."""
    known = {p.name: p for p in load_partitions(path)}
    if not names:
        return list(known.values())
    missing = [n for n in names if n not in known]
    if missing:
        msg = f"no partition {', '.join(missing)} in {path} (it has {', '.join(known)})"
        raise ExperimentError(msg)
    return [known[n] for n in dict.fromkeys(names)]


def throughputs(
    group: Path, configs: list[str], partition: Partition, threads: int, log: Path
) -> dict[str, Any]:
    """Training windows/s of each config, measured once (throughput.json) for all partitions."""
    path = group / "throughput.json"
    rates = read_json(path) if path.is_file() else {}
    for name in configs:
        if name not in rates:
            bench = RunSpec(group / "bench", partition, json.dumps(CONFIGS[name]), threads=threads)
            rate, windows = measure(bench, log)
            rates[name] = {"rate": rate, "windows": windows}
            write_json(path, rates)
    return rates


def _int8(step: Path) -> Path:
    return step.with_name(step.name.removesuffix(".onnx") + ".int8.onnx")


def balanced(steps: list[Path], every: int = 1) -> list[list[Path]]:
    """Two groups of models of about equal cost (FLOPs of the graph eval runs, int8 counted
    at 40 %), so that the two eval processes, one per core, end together."""
    graph = (lambda p: p) if every == 1 else window_graph_for
    cost = {p: graph_flops(graph(p)) * (0.4 if ".int8." in p.name else 1.0) for p in steps}
    bins: list[list[Path]] = [[], []]
    load = [0.0, 0.0]
    for p in sorted(steps, key=cost.__getitem__, reverse=True):
        i = 0 if load[0] <= load[1] else 1
        bins[i].append(p)
        load[i] += cost[p]
    return [b for b in bins if b]


def evaluate(
    group: Path,
    partition: Partition,
    models: dict[str, Path],
    windows: dict[str, int],
    every: int,
    log: Path,
) -> dict[str, Any]:
    """One replay of a partition's held-out sessions per eval process for its fp32 and int8
    models; reports by step-graph path (cached in eval/PARTITION.json by mtime)."""
    out = group / "eval" / f"{partition.name}.json"
    files = partition.test_files()
    steps = [p for m in models.values() for p in (m, _int8(m))]
    stamps = {str(p): p.stat().st_mtime for p in steps} | {
        "files": [str(f) for f in files],
        "every": every,
    }
    if out.is_file() and read_json(out).get("stamps") == stamps:
        COMMANDS.extend(read_json(out).get("commands", []))
        return dict(read_json(out)["reports"])
    first = len(COMMANDS)
    started = time.monotonic()
    reports = []
    for window in sorted({windows[name] for name in models}, reverse=True):
        group_models = [m for name, m in models.items() if windows[name] == window]
        cmds = []
        for half in balanced([p for m in group_models for p in (m, _int8(m))], every):
            args = ["eval", *files, *(a for p in half for a in ("--model", p))]
            args += ["--every", str(every), "--json", "--threads", "1"]
            if window == CONTRACT_WINDOW:
                cmds.append(scotti_command(*args))
            else:  # outside the daemon's contract: see any_window.py
                cmds.append(
                    [sys.executable, str(HERE / "any_window.py"), str(window), *map(str, args)]
                )
        reports += [r for text in run_parallel(cmds, log) for r in _as_list(json.loads(text))]
    by_path = {str(Path(r["model"]["path"]).resolve()): r for r in reports}
    result = {str(p): by_path[str(p.resolve())] | {"partition": partition.name} for p in steps}
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
    choice: dict[str, Any],
    group: Path,
    partitions: list[Partition],
    plans: dict[str, dict[str, Any]],
    evaluated: dict[str, Any],
    out_dir: Path,
    log: Path,
) -> None:
    """The first partition's model of the chosen config and precision, with a card holding
    every partition's figures (their mean and SD)."""
    name, lead = choice["config"], partitions[0]
    plan = plans[lead.name]
    data = (
        f"Simulated corpus (experiments/partitions.json): partition {lead.name}'s "
        f"{len(lead.train)} training subjects ({', '.join(lead.train)}), "
        f"all {NUM_ACTIONS} actions, with the realistic sensor and transport effects. Config "
        f"{name}; {plan['trained_s'] / 60:.1f} min of training on this shared 2-core CPU "
        f"({plan.get('epochs_done', 0)}/{plan['epochs']} epochs at stride {plan['stride']}, "
        f"lr {LEARNING_RATE[CONFIGS[name]['embed_dim']]:g}); undertrained. Chosen by "
        "`python experiments/sweep.py` as the most accurate config (mean over "
        f"{len(partitions)} partitions) whose streaming step stays under 10 ms p99 on one "
        f"thread. The metrics' spread is over the {len(partitions)} subject-wise partitions "
        f"({', '.join(p.name for p in partitions)}): the same config trained once on each "
        f"partition's training subjects and scored on its {len(lead.test)} held-out "
        f"subjects; the shipped weights are {lead.name}'s run."
    )
    cmd = [
        sys.executable,
        str(ROOT / "scripts" / "ship_default.py"),
        str(group / "models" / f"{name}-{lead.name}.onnx"),  # NAME.onnx; --int8 picks the copy
        *(["--int8"] if choice["precision"] == "int8" else []),
    ]
    reports, commands = [], []
    for part, path in choice["paths"].items():
        report = group / "ship" / f"{part}.json"
        write_json(report, evaluated[path])
        reports.append(str(report))
        commands += ["--eval-command", _command_of(Path(path))]
    cmd += ["--eval", *reports, *commands]  # --eval takes them all at once
    every = evaluated[choice["paths"][lead.name]]["every"]
    cmd += [
        "--out-dir",
        str(out_dir),
        "--from",
        str((group / name / lead.name / "last.pt").relative_to(ROOT)),
        "--data",
        data,
        "--note",
        f"Metrics: mean ± sample SD over {len(choice['paths'])} partitions (n = "
        f"{len(choice['paths'])}), each partition's figures pooled over its held-out "
        f"subjects; {scoring(every)}. Latency below: the streaming step.",
    ]
    run(cmd, log)


def _command_of(path: Path) -> str:
    return next(
        (c for c in COMMANDS if " eval " in c and path.name + " " in c + " "),
        "scotti eval (see docs/accuracy-vs-latency.md)",
    )


if __name__ == "__main__":
    raise SystemExit(main())
