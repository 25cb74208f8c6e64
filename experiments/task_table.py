"""Table 3 on the current corpus: the multi-task model against single-task variants.

    python experiments/task_table.py multi:p3=runs/v9-p3/eval/test.json \\
        progress:p3=runs/v9-p3-progress/eval/test.json \\
        action:p3=runs/v9-p3-action/eval/test.json \\
        --run multi:p3=runs/v9-p3 --run progress:p3=runs/v9-p3-progress \\
        [--write docs/evaluation.md]

Each VARIANT:PARTITION=REPORT is the ``scotti eval --json`` report of one
model (the first of a list) on that partition's held-out subjects; VARIANT is
``multi`` or the single task the model was trained on (``pose``, ``action``,
``progress``: experiments/partition_runs.py ``--variant``). Each single-task
model is compared with the multi-task model of the same partition, on the
metrics of its task only, and per action (accuracy for ``action``, progress
MSE and APP for ``progress``), since the question is where sharing the encoder
helps or hurts. With several partitions the differences are paired by
partition and given as mean ± SD; with one, as that partition's figure, which
says nothing about the spread. ``--run VARIANT:PARTITION=RUN_DIR`` adds how
each run's training ended. ``--write DOC`` puts the Markdown between the
``<!-- tasks:begin -->`` and ``<!-- tasks:end -->`` lines of DOC
(``--section NAME``: the ``<!-- NAME:begin/end -->`` ones, so a second recipe's
Table 3 can stand beside the first).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

from common import ExperimentError, fmt, mean_sd, table, utc_now, write_section
from partition_table import check_held_out, load_report, pairs, run_lines
from tables_doc import METRICS, ROW_NAMES, TASK_OF

SECTION = "tasks"
BEGIN, END = f"<!-- {SECTION}:begin -->", f"<!-- {SECTION}:end -->"
VARIANTS = ("pose", "action", "progress")
PER_ACTION = {
    "pose": ("mpjpe_mm",),
    "action": ("action_accuracy",),
    "progress": ("progress_mse", "app"),
}

Key = tuple[str, str]  # (variant, partition)


def split_key(name: str) -> Key:
    variant, sep, partition = name.partition(":")
    if not sep or variant not in ("multi", *VARIANTS) or not partition:
        raise ExperimentError(
            f"{name!r}: expected VARIANT:PARTITION, VARIANT one of multi, pose, action, progress"
        )
    return variant, partition


def compared(reports: dict[Key, dict[str, Any]]) -> dict[str, list[str]]:
    """Single-task variant -> the partitions where both it and the multi-task model were scored."""
    out: dict[str, list[str]] = {}
    for variant, partition in reports:
        if variant != "multi" and ("multi", partition) in reports:
            out.setdefault(variant, []).append(partition)
    if not out:
        raise ExperimentError(
            "no single-task report with a multi-task report of the same partition"
        )
    return out


def _metrics(keys: tuple[str, ...]) -> list[tuple[str, str, int, float, bool]]:
    return [m for m in METRICS if m[0] in keys]


def task_rows(reports: dict[Key, dict[str, Any]], pairs_: dict[str, list[str]]) -> list[str]:
    """One row per task: the figures of both models and their paired difference."""
    rows, verdicts = [], []
    for variant, partitions in pairs_.items():
        for key, column, d, s, lower in _metrics(
            tuple(k for k, v in TASK_OF.items() if v == variant)
        ):
            single = [reports[(variant, p)]["metrics"][key] for p in partitions]
            multi = [reports[("multi", p)]["metrics"][key] for p in partitions]
            delta = [b - a for a, b in zip(single, multi, strict=True)]
            rows.append(
                [
                    column,
                    ", ".join(partitions),
                    fmt(single, d, s),
                    fmt(multi, d, s),
                    fmt(delta, d, s),
                ]
            )
            verdicts.append(_verdict(column, variant, delta, d, s, lower))
    header = ["metric", "partitions", "single-task", "multi-task", "multi - single"]
    return [*table(header, rows), "", *verdicts]


def _verdict(column: str, variant: str, delta: list[float], d: int, s: float, lower: bool) -> str:
    mean, sd = mean_sd(delta)
    better = (mean < 0) == lower
    said = f"{'+' if mean >= 0 else ''}{mean * s:.{d}f}"
    versus = f"multi-task minus {variant}-only"
    if len(delta) > 1:
        clear = abs(mean) > sd
        word = ("helps" if better else "hurts") if clear else "makes no clear difference"
        return f"- {column}: sharing {word} ({said} ± {sd * s:.{d}f}, {versus})."
    side = "better" if better else "worse"
    return f"- {column}: {versus} {said}, the multi-task model {side}; one partition, no spread."


def per_action_rows(reports: dict[Key, dict[str, Any]], pairs_: dict[str, list[str]]) -> list[str]:
    """Per action, each single task's own metrics for both models (mean over partitions)."""
    columns = [(v, m) for v in PER_ACTION if v in pairs_ for m in _metrics(PER_ACTION[v])]
    if not columns:
        return []
    header = ["action"]
    for variant, (_, column, _, _, _) in columns:
        header += [f"{column}, {variant}-only", f"{column}, multi-task"]
    any_report = next(iter(reports.values()))
    rows = []
    for action in any_report["per_action"]:
        cells = [ROW_NAMES.get(action, action)]
        for variant, (key, _, d, s, _) in columns:
            for who in (variant, "multi"):
                got = [
                    _num(reports[(who, p)]["per_action"][action].get(key)) for p in pairs_[variant]
                ]
                cells.append(fmt(got, d, s))
        if any(c != "-" for c in cells[1:]):
            rows.append(cells)
    return table(header, rows)


def _num(x: Any) -> float:
    return float(x) if isinstance(x, (int, float)) else math.nan


def markdown(reports: dict[Key, dict[str, Any]], runs: dict[Key, Path], command: str) -> str:
    pairs_ = compared(reports)
    lines = [
        f"Written by `{command}` ({utc_now()}) from the `scotti eval --json` reports named",
        "there: every model scored on its partition's held-out subjects through the daemon's",
        "streaming path. A single-task model is compared on its own task's metrics only.",
        "",
        *task_rows(reports, pairs_),
    ]
    per_action = per_action_rows(reports, pairs_)
    if per_action:
        lines += ["", "Per action, each single task's metrics:", "", *per_action]
    if runs:
        named = {f"{p} {v}": d for (v, p), d in runs.items()}
        lines += ["", "How each model's training ended (validation subjects only):", ""]
        lines += run_lines(named)
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python experiments/task_table.py",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("reports", nargs="+", metavar="VARIANT:PARTITION=REPORT")
    parser.add_argument("--run", action="append", default=[], metavar="VARIANT:PARTITION=RUN_DIR")
    parser.add_argument("--write", type=Path, help="replace the marked section of this doc")
    parser.add_argument("--section", default=SECTION, help="which marked section (default tasks)")
    args = parser.parse_args(argv)
    command = "python experiments/task_table.py " + " ".join(
        argv if argv is not None else sys.argv[1:]
    )
    try:
        reports = {
            split_key(n): load_report(p, "") for n, p in pairs(args.reports, "report").items()
        }
        for (variant, partition), report in reports.items():
            check_held_out(f"{variant}:{partition}", report)
        runs = {split_key(n): d for n, d in pairs(args.run, "--run").items()}
        text = markdown(reports, runs, command)
        if args.write:
            write_section(args.write, text, args.section)
    except (ExperimentError, OSError, KeyError, ValueError) as exc:
        print(f"task_table: {exc}", file=sys.stderr)
        return 1
    print(text, end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
