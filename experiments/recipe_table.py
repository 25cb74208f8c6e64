"""Two training recipes of the same network, model by model on the same held-out people.

    python experiments/recipe_table.py plain:p2=runs/v9-p2/eval/test.json \\
        crosstalk:p2=runs/v9-p2-xt0.03/eval/test.json \\
        --run plain:p2=runs/v9-p2 --run crosstalk:p2=runs/v9-p2-xt0.03 \\
        [--base plain] [--write docs/evaluation.md]

Each RECIPE:PARTITION=REPORT is the ``scotti eval --json`` report (the first
model of its list) of a model trained on that partition's training subjects
with one recipe (say without and with an augmentation), scored on the
partition's held-out subjects. Every other recipe is compared with ``--base``
(default: the first named) where both were scored on the same partition, and
the reports must hold the same session files: the comparison is paired, person
by person. Prints the pooled figures, each held-out subject's, and each
action's; ``--write DOC`` puts them between the ``<!-- recipes:begin -->``
and ``<!-- recipes:end -->`` lines of DOC (``--section NAME``: the
``<!-- NAME:begin -->`` ones). A REPORT written as FILE#PIECE is the model of
FILE whose path contains PIECE: two models scored in one replay (say a model
and the one it was trained on from, as ``partition_runs.py --init`` scores them)
are compared frame for frame.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

from common import ExperimentError, fmt, table, utc_now, write_section
from partition_table import check_held_out, pairs, report_of, run_lines
from tables_doc import METRICS, ROW_NAMES

PER_SUBJECT = ("mpjpe_mm", "action_accuracy", "progress_mse", "app")
PER_ACTION = ("action_accuracy", "progress_mse")

Key = tuple[str, str]  # (recipe, partition)


def split_key(name: str) -> Key:
    recipe, sep, partition = name.partition(":")
    if not sep or not recipe or not partition:
        raise ExperimentError(f"{name!r}: expected RECIPE:PARTITION")
    return recipe, partition


def paired(reports: dict[Key, dict[str, Any]], base: str) -> dict[str, list[str]]:
    """Recipe -> the partitions where it and the base recipe were scored on the same files."""
    out: dict[str, list[str]] = {}
    for recipe, partition in reports:
        if recipe == base or (base, partition) not in reports:
            continue
        mine = _files(reports[(recipe, partition)])
        theirs = _files(reports[(base, partition)])
        if mine != theirs:
            raise ExperimentError(
                f"{recipe}:{partition} and {base}:{partition} were scored on different sessions"
            )
        out.setdefault(recipe, []).append(partition)
    if not out:
        raise ExperimentError(f"no recipe scored on a partition where {base!r} was scored too")
    return out


def _files(report: dict[str, Any]) -> list[str]:
    return sorted(Path(s["path"]).name for s in report["sessions"])


def _metric(key: str) -> tuple[str, str, int, float, bool]:
    return next(m for m in METRICS if m[0] == key)


def pooled_rows(
    reports: dict[Key, dict[str, Any]], base: str, pairs_: dict[str, list[str]]
) -> list[str]:
    header = ["metric", "recipe", "partitions", base, "recipe", f"recipe - {base}"]
    rows = []
    for recipe, partitions in pairs_.items():
        for key, column, d, s, _ in METRICS:
            before = [reports[(base, p)]["metrics"][key] for p in partitions]
            after = [reports[(recipe, p)]["metrics"][key] for p in partitions]
            delta = [b - a for a, b in zip(before, after, strict=True)]
            rows.append(
                [column, recipe, ", ".join(partitions), fmt(before, d, s), fmt(after, d, s),
                 fmt(delta, d, s)]
            )  # fmt: skip
        before = [_unfamiliar(reports[(base, p)]) for p in partitions]
        after = [_unfamiliar(reports[(recipe, p)]) for p in partitions]
        delta = [b - a for a, b in zip(before, after, strict=True)]
        rows.append(
            ["unfamiliar (%)", recipe, ", ".join(partitions), fmt(before, 2, 100.0),
             fmt(after, 2, 100.0), fmt(delta, 2, 100.0)]
        )  # fmt: skip
    return table(header, rows)


def _unfamiliar(report: dict[str, Any]) -> float:
    """The share flagged unfamiliar (a dash for a model exported before the score)."""
    return _num(report.get("ood", {}).get("unfamiliar"))


def _side_by_side(first: str, keys: tuple[str, ...], base: str) -> list[str]:
    """A header with each metric twice: under the base recipe, then under the other."""
    header = [first, "recipe"]
    for key in keys:
        column = _metric(key)[1]
        header += [f"{column}, {base}", f"{column}, recipe"]
    return header


def subject_rows(
    reports: dict[Key, dict[str, Any]], base: str, pairs_: dict[str, list[str]]
) -> list[str]:
    """Each held-out person under both recipes: where a recipe helps, and whom."""
    header = _side_by_side("subject", PER_SUBJECT, base)
    rows = []
    for recipe, partitions in pairs_.items():
        for p in partitions:
            before = {s["subject"]: s["metrics"] for s in reports[(base, p)]["sessions"]}
            for session in reports[(recipe, p)]["sessions"]:
                cells = [f"{session['subject']} ({p})", recipe]
                for key in PER_SUBJECT:
                    _, _, d, s, _ = _metric(key)
                    cells += [
                        fmt([before[session["subject"]][key]], d, s),
                        fmt([session["metrics"][key]], d, s),
                    ]
                rows.append(cells)
    return table(header, rows)


def action_rows(
    reports: dict[Key, dict[str, Any]], base: str, pairs_: dict[str, list[str]]
) -> list[str]:
    header = _side_by_side("action", PER_ACTION, base)
    rows = []
    for recipe, partitions in pairs_.items():
        for action in reports[(base, partitions[0])]["per_action"]:
            cells = [ROW_NAMES.get(action, action), recipe]
            for key in PER_ACTION:
                _, _, d, s, _ = _metric(key)
                for who in (base, recipe):
                    got = [
                        _num(reports[(who, p)]["per_action"][action].get(key)) for p in partitions
                    ]
                    cells.append(fmt(got, d, s))
            if any(c != "-" for c in cells[2:]):
                rows.append(cells)
    return table(header, rows)


def _num(x: Any) -> float:
    return float(x) if isinstance(x, (int, float)) else math.nan


def markdown(
    reports: dict[Key, dict[str, Any]], runs: dict[Key, Path], base: str, command: str
) -> str:
    pairs_ = paired(reports, base)
    lines = [
        f"Written by `{command}` ({utc_now()}) from the `scotti eval --json` reports named",
        "there: each model scored on its partition's held-out subjects through the daemon's",
        f"streaming path; every recipe against `{base}` on the same session files.",
        "",
        *pooled_rows(reports, base, pairs_),
        "",
        "Per held-out subject:",
        "",
        *subject_rows(reports, base, pairs_),
        "",
        "Per action (recall, and progress MSE where progress is labelled), pooled frames:",
        "",
        *action_rows(reports, base, pairs_),
    ]
    if runs:
        named = {f"{r} on {p}": d for (r, p), d in runs.items()}
        lines += ["", "How each model's training ended (validation subjects only):", ""]
        lines += run_lines(named)
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python experiments/recipe_table.py",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("reports", nargs="+", metavar="RECIPE:PARTITION=REPORT")
    parser.add_argument("--run", action="append", default=[], metavar="RECIPE:PARTITION=RUN_DIR")
    parser.add_argument("--base", help="the recipe the others are compared with (default: first)")
    parser.add_argument("--write", type=Path, help="replace the marked section of this doc")
    parser.add_argument("--section", default="recipes", help="which marked section of --write")
    args = parser.parse_args(argv)
    command = "python experiments/recipe_table.py " + " ".join(
        argv if argv is not None else sys.argv[1:]
    )
    try:
        reports = {split_key(n): report_of(p) for n, p in pairs(args.reports, "report").items()}
        for (recipe, partition), report in reports.items():
            check_held_out(f"{recipe}:{partition}", report)
        base = args.base or next(iter(reports))[0]
        runs = {split_key(n): d for n, d in pairs(args.run, "--run").items()}
        text = markdown(reports, runs, base, command)
        if args.write:
            write_section(args.write, text, args.section)
    except (ExperimentError, OSError, KeyError, ValueError) as exc:
        print(f"recipe_table: {exc}", file=sys.stderr)
        return 1
    print(text, end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
