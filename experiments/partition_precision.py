"""fp32 against int8, and streaming against recompute, for the partition models.

    python experiments/partition_precision.py p1=runs/v7c-p1/eval/ship.json \\
        p2=runs/v9-p2/eval/test.json p3=runs/v9-p3/eval/test.json \\
        [--write docs/accuracy-vs-latency.md]

Each REPORT is the fp32 ``scotti eval --json`` report of one partition's model
on that partition's held-out subjects (what experiments/partition_table.py
reads; the first model of a list, or ``--pick``). For each, the same graphs are
quantized as ``scotti export --int8`` does (MatMul/Gemm weights to int8; the
model's metadata, progress map and unfamiliar statistics kept) into
``MODEL_DIR/int8/`` and scored by ``scotti eval --json`` on the same session
files, through the same streaming path, into ``REPORT_DIR/int8.json``: so the
accuracy lost to int8 is measured per partition, on held-out people. Then the
first partition's fp32 and int8 graphs are timed by experiments/measure.py
(the daemon's streaming step against recomputing the whole window; the weights
do not change the cost). Resumable: a quantized graph or an int8 report that is
newer than its source is reused. ``--write DOC`` puts the Markdown between the
``<!-- precision:begin -->`` and ``<!-- precision:end -->`` lines of DOC.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from common import (
    ROOT,
    ExperimentError,
    fmt,
    from_root,
    run,
    scoring,
    scotti_command,
    table,
    utc_now,
    write_between_markers,
)
from measure import describe
from partition_table import check_held_out, load_report, pairs
from scotti.models.runtime import window_graph_for
from tables_doc import METRICS

BEGIN, END = "<!-- precision:begin -->", "<!-- precision:end -->"


def _fresh(out: Path, src: Path) -> bool:
    return out.is_file() and out.stat().st_mtime >= src.stat().st_mtime


def int8_copy(model: Path) -> Path:
    """The step and window graphs quantized beside the model, in int8/; the step graph."""
    from scotti.export.quantize import quantize_int8  # onnxruntime's quantizer: not the daemon's

    out_dir = model.parent / "int8"
    out_dir.mkdir(exist_ok=True)
    for graph in (model, window_graph_for(model)):
        dst = out_dir / graph.name
        if not _fresh(dst, graph):
            quantize_int8(graph, dst)
    return out_dir / model.name


def score_int8(report_path: Path, report: dict[str, Any], int8: Path) -> dict[str, Any]:
    """The int8 graphs on the fp32 report's own session files, scored the same way."""
    out = report_path.with_name("int8.json")
    if not _fresh(out, int8):
        sessions = [ROOT / s["path"] for s in report["sessions"]]
        every = ["--every", str(report["every"])] if report.get("every", 1) != 1 else []
        log = report_path.with_name("int8.log")
        text = run(scotti_command("eval", *sessions, "--model", int8, *every, "--json"), log)
        out.write_text(text)
    value = json.loads(out.read_text())
    return dict(value[0] if isinstance(value, list) else value)


def _unfamiliar(report: dict[str, Any]) -> float:
    return float((report.get("ood") or {}).get("unfamiliar", 0.0))


def accuracy_rows(pairs_: dict[str, tuple[dict[str, Any], dict[str, Any]]]) -> list[str]:
    """Per partition fp32 and int8; then mean ± SD of each, and the paired difference."""
    header = ["partition", "precision", *(c for _, c, _, _, _ in METRICS), "unfamiliar (%)"]
    rows = []
    for name, (fp32, int8) in pairs_.items():
        for label, r in (("fp32", fp32), ("int8", int8)):
            cells = [name, label]
            cells += [fmt([r["metrics"][k]], d, s) for k, _, d, s, _ in METRICS]
            cells.append(f"{100 * _unfamiliar(r):.2f}")
            rows.append(cells)
    for label, idx in (("fp32", 0), ("int8", 1)):
        cells = [f"mean ± SD ({len(pairs_)})", label]
        cells += [
            fmt([p[idx]["metrics"][k] for p in pairs_.values()], d, s) for k, _, d, s, _ in METRICS
        ]
        cells.append(fmt([_unfamiliar(p[idx]) for p in pairs_.values()], 2, 100))
        rows.append(cells)
    diff = ["int8 - fp32 (paired)", ""]
    for key, _, d, s, _ in METRICS:
        delta = [p[1]["metrics"][key] - p[0]["metrics"][key] for p in pairs_.values()]
        diff.append(fmt(delta, d + 1, s))  # one more digit: the differences are small
    diff.append(fmt([_unfamiliar(i) - _unfamiliar(f) for f, i in pairs_.values()], 3, 100))
    rows.append(diff)
    return table(header, rows)


def latency_rows(timed: dict[str, dict[str, Any]], fp32: Path, int8: Path) -> list[str]:
    header = [
        "precision",
        "size MB (step+window)",
        "MFLOPs/frame step",
        "MFLOPs/frame recompute",
        "step ms median / p99, 1 thread",
        "step ms median / p99, 2 threads",
        "recompute ms median / p99, 1 thread",
        "step vs fp32 step (1 thread)",
        "recompute vs step (1 thread)",
    ]
    base = timed[str(fp32)]["latency"]["1"]["step_median_ms"]
    rows = []
    for label, path in (("fp32", fp32), ("int8", int8)):
        m = timed[str(path)]
        one, two = m["latency"]["1"], m["latency"]["2"]
        rows.append(
            [
                label,
                f"{m['bytes'] / 1e6:.1f}",
                f"{m['step_flops'] / 1e6:.0f}",
                f"{m['window_flops'] / 1e6:.0f}",
                f"{one['step_median_ms']:.2f} / {one['step_p99_ms']:.2f}",
                f"{two['step_median_ms']:.2f} / {two['step_p99_ms']:.2f}",
                f"{one['window_median_ms']:.2f} / {one['window_p99_ms']:.2f}",
                f"{one['step_median_ms'] / base:.2f}x",
                f"{one['window_median_ms'] / one['step_median_ms']:.1f}x",
            ]
        )
    return table(header, rows)


def markdown(
    pairs_: dict[str, tuple[dict[str, Any], dict[str, Any]]],
    timed: dict[str, dict[str, Any]],
    graphs: tuple[Path, Path],
    steps: int,
    command: str,
) -> str:
    lead = next(iter(pairs_))
    every = int(next(iter(pairs_.values()))[0].get("every", 1))
    lines = [
        f"Written by `{command}` ({utc_now()}).",
        "",
        "Accuracy: each partition's own model (fp32) and the same graphs quantized to int8",
        "(MatMul/Gemm weights, as `scotti export --int8`), scored on that partition's held-out",
        f"subjects ({scoring(every)}), in separate replays of the same session files:",
        "",
        *accuracy_rows(pairs_),
        "",
        f"Cost per frame: {lead}'s graphs (`{from_root(graphs[0])}` and its int8 copy),",
        f"{steps} calls each after a warm-up, models taking turns call by call (experiments/",
        "measure.py). `step` is the daemon's call (one new frame and the cached embeddings,",
        "batch 1); `recompute` is one call of the window graph over all T frames, what a",
        "daemon without the embedding cache would pay every frame. The ratios compare figures",
        "of the same run; the absolute times depend on what else the machine was doing.",
        "",
        *latency_rows(timed, *graphs),
    ]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python experiments/partition_precision.py",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("reports", nargs="+", metavar="NAME=REPORT")
    parser.add_argument("--pick", default="", help="the model whose path contains this")
    parser.add_argument("--steps", type=int, default=400, help="timed calls per graph")
    parser.add_argument("--write", type=Path, help="replace the marked section of this doc")
    args = parser.parse_args(argv)
    command = "python experiments/partition_precision.py " + " ".join(
        argv if argv is not None else sys.argv[1:]
    )
    try:
        results = {}
        for name, path in pairs(args.reports, "report").items():
            fp32 = load_report(path, args.pick)
            check_held_out(name, fp32)
            int8 = int8_copy(ROOT / fp32["model"]["path"])
            results[name] = (fp32, score_int8(path, fp32, int8), int8)
        fp32_graph = ROOT / next(iter(results.values()))[0]["model"]["path"]
        graphs = (fp32_graph, next(iter(results.values()))[2])
        timed = describe(list(graphs), [1, 2], args.steps)
        pairs_ = {n: (f, i) for n, (f, i, _) in results.items()}
        text = markdown(pairs_, timed, graphs, args.steps, command)
        if args.write:
            write_between_markers(args.write, text, BEGIN, END)
    except (ExperimentError, OSError, KeyError, ValueError) as exc:
        print(f"partition_precision: {exc}", file=sys.stderr)
        return 1
    print(text, end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
