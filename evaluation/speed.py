"""How fast ``scotti eval`` runs, configurations side by side in one run (A/B).

    python -m scotti.evaluation.speed SESSIONS... --config "--jobs 1" \\
        --config "--jobs 2" [--config ...] [--repeats 3] [--model M]

Each configuration is a set of ``scotti eval`` options. The runs take turns
(A, B, A, B, ...), each a fresh ``scotti eval --json`` process, so that the load
other work puts on a shared host weighs on all of them alike; the table gives
each configuration's frames per second of wall time (min and median over the
repeats), the process's CPU milliseconds per paired frame and the model's
part of them (from the report's ``rate``), and the 1-minute load average
after the runs. Every run of one model must score the same figures (a change
of speed that changes the predictions is a bug), or the command says which
configuration differs and exits 1. A measurement, not a test.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import statistics
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

# The report's parts that the predictions decide: equal across configurations.
_SCORED = ("metrics", "per_action", "confusion", "ood", "predictions", "pairs")


@dataclass
class Runs:
    """One configuration's repeats."""

    options: list[str]
    frames_per_s: list[float] = field(default_factory=list)
    cpu_ms_per_frame: list[float] = field(default_factory=list)
    model_ms_per_frame: list[float] = field(default_factory=list)
    loads: list[float] = field(default_factory=list)  # 1-minute load average after each


def eval_once(sessions: Sequence[Path], options: Sequence[str]) -> dict[str, Any]:
    """One ``scotti eval --json`` in a process of its own: its report (the first model's)."""
    cmd = [sys.executable, "-m", "scotti.cli.main", "eval", *map(str, sessions), "--json"]
    done = subprocess.run([*cmd, *options], capture_output=True, text=True, check=False)
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or ["no message"])[-1]
        msg = f"scotti eval {shlex.join(options)} exited {done.returncode}: {last}"
        raise RuntimeError(msg)
    report = json.loads(done.stdout)
    return dict(report[0] if isinstance(report, list) else report)


def measure(
    sessions: Sequence[Path], configs: Sequence[Sequence[str]], repeats: int
) -> tuple[list[Runs], list[str]]:
    """Every configuration ``repeats`` times, in turns; also what differed in the scores."""
    runs = [Runs(list(c)) for c in configs]
    first: dict[str, dict[str, Any]] = {}  # by model: the first run's scores
    differ: list[str] = []
    for _ in range(repeats):
        for r in runs:
            report = eval_once(sessions, r.options)
            rate = report["rate"]
            frames = rate["paired_frames"]
            r.frames_per_s.append(frames / rate["seconds"])
            r.cpu_ms_per_frame.append(1e3 * rate["cpu_seconds"] / frames)
            r.model_ms_per_frame.append(1e3 * rate["model_cpu_seconds"] / frames)
            r.loads.append(os.getloadavg()[0])
            scored = {k: report.get(k) for k in _SCORED}
            model = report["model"]["sha256"]
            if first.setdefault(model, scored) != scored:
                parts = [k for k in _SCORED if scored[k] != first[model][k]]
                differ.append(f"{shlex.join(r.options) or '(defaults)'}: {', '.join(parts)}")
    return runs, differ


def table(runs: Sequence[Runs]) -> list[str]:
    lines = [
        "| options | frames/s, min | median | max | CPU ms per frame, median "
        "| of it the model | load average (1 min) |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in runs:
        lines.append(
            f"| `{shlex.join(r.options) or '(defaults)'}` | {min(r.frames_per_s):,.0f} "
            f"| {statistics.median(r.frames_per_s):,.0f} | {max(r.frames_per_s):,.0f} "
            f"| {statistics.median(r.cpu_ms_per_frame):.3f} "
            f"| {statistics.median(r.model_ms_per_frame):.3f} "
            f"| {min(r.loads):.1f}-{max(r.loads):.1f} |"
        )
    return lines


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m scotti.evaluation.speed",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("sessions", nargs="+", type=Path, help="session files or directories")
    parser.add_argument(
        "--config",
        action="append",
        required=True,
        metavar="OPTIONS",
        help='scotti eval options of one configuration, quoted ("--jobs 2 --batch 32"); '
        "repeat it for each",
    )
    parser.add_argument("--repeats", type=int, default=3, help="runs of each configuration")
    args = parser.parse_args(argv)
    if args.repeats < 1:
        print("speed: --repeats must be at least 1", file=sys.stderr)
        return 2
    configs = [shlex.split(c) for c in args.config]
    started = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    print(
        f"scotti eval speed, {started}, {os.cpu_count()} cores, "
        f"load average before {os.getloadavg()[0]:.1f}, {args.repeats} runs each in turns",
        flush=True,
    )
    try:
        runs, differ = measure(args.sessions, configs, args.repeats)
    except (RuntimeError, json.JSONDecodeError) as exc:
        print(f"speed: {exc}", file=sys.stderr)
        return 2
    print("\n".join(table(runs)))
    if differ:
        print("speed: the scores differ from the first run's:", file=sys.stderr)
        for line in differ:
            print(f"  {line}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
