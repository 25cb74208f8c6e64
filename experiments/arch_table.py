"""Width, depth and window, each trained to its plateau: accuracy against cost.

    python experiments/arch_table.py E128-L2-T40:p3=runs/v9-p3/eval/test.json \\
        E128-L2-T20:p3=runs/v9-p3-E128-L2-T20/eval/test.json \\
        E256-L2-T40:p3=runs/v9-p3-E256-L2-T40/eval/test.json \\
        --run E128-L2-T40:p3=runs/v9-p3 --run E256-L2-T40:p3=runs/v9-p3-E256-L2-T40 \\
        [--write docs/accuracy-vs-latency.md]

Each CONFIG:PARTITION=REPORT is the ``scotti eval --json`` report (the first
model of its list) of a model of that configuration (experiments/configs.py),
trained by ``experiments/partition_runs.py --arch CONFIG`` on the partition's
training subjects until its plateau, calibrated, and scored on that
partition's held-out subjects through the daemon's streaming path. Figures are
the mean ± SD over the partitions each config was scored on; the paired
columns compare each config with ``--baseline`` on the partitions both have.
Cost comes from experiments/measure.py on each config's first model (the
streaming step as the daemon calls it against recomputing the window; the
weights do not change it), all configs taking turns call by call in one run,
so its ratios compare like with like. ``--write DOC`` puts the Markdown
between the ``<!-- archs:begin -->`` and ``<!-- archs:end -->`` lines of DOC
(``--section NAME``: the ``<!-- NAME:begin -->`` ones). A REPORT written as
``FILE#PIECE`` takes the model of FILE whose path contains PIECE instead of the
first (a report that scored a fine-tuned model beside the shipped one).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

from common import ExperimentError, fmt, table, utc_now, write_section
from configs import CONFIGS, window_of
from measure import describe
from partition_table import check_held_out, pairs, report_of, run_lines
from tables_doc import METRICS

SECTION = "archs"  # the doc's <!-- archs:begin --> ... <!-- archs:end --> lines

Key = tuple[str, str]  # (config, partition)


def split_key(name: str) -> Key:
    config, sep, partition = name.partition(":")
    if not sep or config not in CONFIGS or not partition:
        raise ExperimentError(
            f"{name!r}: expected CONFIG:PARTITION, CONFIG one of {', '.join(CONFIGS)}"
        )
    return config, partition


def check_configs(reports: dict[Key, dict[str, Any]]) -> None:
    """Each report's model has its config's width and window: a mislabelled report fails."""
    for (config, partition), report in reports.items():
        model = report["model"]
        want = (CONFIGS[config]["embed_dim"], window_of(config))
        got = (model.get("embed_dim"), model.get("window"))
        if got != want:
            raise ExperimentError(
                f"{config}:{partition}: the report's model has E={got[0]}, T={got[1]}, "
                f"not E={want[0]}, T={want[1]}"
            )


def by_config(reports: dict[Key, dict[str, Any]]) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for config, partition in reports:
        out.setdefault(config, []).append(partition)
    return {c: out[c] for c in CONFIGS if c in out}  # the configs' order, narrow to wide


def cost_of(reports: dict[Key, dict[str, Any]], steps: int) -> dict[str, dict[str, Any]]:
    """Per config: size, FLOPs and latency of its first model, all measured in one run."""
    models = {c: Path(reports[(c, ps[0])]["model"]["path"]) for c, ps in by_config(reports).items()}
    measured = describe(list(models.values()), [1], steps)
    return {c: measured[str(path)] for c, path in models.items()}


def accuracy_rows(
    reports: dict[Key, dict[str, Any]], cost: dict[str, dict[str, Any]], baseline: str
) -> list[str]:
    header = ["config", "partitions", *(m[1] for m in METRICS), "unfamiliar (%)"]
    header += ["size MB (step+window)", "MFLOPs/frame step", "MFLOPs/frame recompute"]
    header += ["step ms median / p99, 1 thread", "recompute ms median, 1 thread"]
    header += [f"step vs {baseline}"]
    base_ms = cost.get(baseline, {}).get("latency", {}).get("1", {}).get("step_median_ms")
    rows = []
    for config, partitions in by_config(reports).items():
        got = [reports[(config, p)] for p in partitions]
        cells = [config, ", ".join(partitions)]
        cells += [fmt([r["metrics"][key] for r in got], d, s) for key, _, d, s, _ in METRICS]
        # Reports of models exported before the unfamiliar score have no share: a dash.
        cells.append(fmt([r.get("ood", {}).get("unfamiliar", math.nan) for r in got], 2, 100.0))
        c = cost[config]
        ms = c["latency"]["1"]
        cells += [
            f"{c['bytes'] / 1e6:.1f}",
            f"{c['step_flops'] / 1e6:.0f}",
            f"{c['window_flops'] / 1e6:.0f}",
            f"{ms['step_median_ms']:.2f} / {ms['step_p99_ms']:.2f}",
            f"{ms['window_median_ms']:.2f}",
            f"{ms['step_median_ms'] / base_ms:.2f}x" if base_ms else "-",
        ]
        rows.append(cells)
    return table(header, rows)


def paired_rows(reports: dict[Key, dict[str, Any]], baseline: str) -> list[str]:
    """Each config minus the baseline, partition by partition (where both were scored)."""
    header = ["config", "partitions", *(f"{m[1]} - {baseline}" for m in METRICS)]
    rows = []
    for config, partitions in by_config(reports).items():
        shared = [p for p in partitions if (baseline, p) in reports]
        if config == baseline or not shared:
            continue
        cells = [config, ", ".join(shared)]
        for key, _, d, s, _ in METRICS:
            delta = [
                reports[(config, p)]["metrics"][key] - reports[(baseline, p)]["metrics"][key]
                for p in shared
            ]
            cells.append(fmt(delta, d, s))
        rows.append(cells)
    return table(header, rows) if rows else []


def markdown(
    reports: dict[Key, dict[str, Any]],
    cost: dict[str, dict[str, Any]],
    runs: dict[Key, Path],
    baseline: str,
    command: str,
) -> str:
    spread = {len(ps) for ps in by_config(reports).values()}
    lines = [
        f"Written by `{command}` ({utc_now()}) from the `scotti eval --json` reports named",
        "there: each model scored on its partition's held-out subjects through the daemon's",
        "streaming path. Accuracy columns: mean ± SD over the partitions named"
        + (" (one partition: no spread)." if spread == {1} else "."),
        "Cost: one run of experiments/measure.py, the configs taking turns call by call.",
        "",
        *accuracy_rows(reports, cost, baseline),
    ]
    paired = paired_rows(reports, baseline)
    if paired:
        lines += ["", f"Against {baseline}, paired by partition:", "", *paired]
    if runs:
        named = {f"{c} on {p}": d for (c, p), d in runs.items()}
        lines += ["", "How each model's training ended (validation subjects only):", ""]
        lines += run_lines(named)
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python experiments/arch_table.py",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("reports", nargs="+", metavar="CONFIG:PARTITION=REPORT")
    parser.add_argument("--run", action="append", default=[], metavar="CONFIG:PARTITION=RUN_DIR")
    parser.add_argument("--baseline", default="E128-L2-T40", choices=list(CONFIGS))
    parser.add_argument("--steps", type=int, default=400, help="timed calls per graph")
    parser.add_argument("--write", type=Path, help="replace the marked section of this doc")
    parser.add_argument("--section", default=SECTION, help="which marked section (default archs)")
    args = parser.parse_args(argv)
    command = "python experiments/arch_table.py " + " ".join(
        argv if argv is not None else sys.argv[1:]
    )
    try:
        reports = {split_key(n): report_of(p) for n, p in pairs(args.reports, "report").items()}
        for (config, partition), report in reports.items():
            check_held_out(f"{config}:{partition}", report)
        check_configs(reports)
        runs = {split_key(n): d for n, d in pairs(args.run, "--run").items()}
        text = markdown(reports, cost_of(reports, args.steps), runs, args.baseline, command)
        if args.write:
            write_section(args.write, text, args.section)
    except (ExperimentError, OSError, KeyError, ValueError) as exc:
        print(f"arch_table: {exc}", file=sys.stderr)
        return 1
    print(text, end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
