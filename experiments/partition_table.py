"""Held-out figures over the subject-wise partitions, one model per partition.

    python experiments/partition_table.py p1=runs/v7c-p1/eval/ship.json \\
        p2=runs/v9-p2/eval/test.json p3=runs/v9-p3/eval/test.json \\
        --run p1=runs/v7-p1 --run p2=runs/v9-p2 --run p3=runs/v9-p3 \\
        [--write docs/evaluation.md]

Each REPORT is what ``scotti eval --json`` printed for one partition's model on
that partition's held-out subjects (a list when several ``--model`` were
scored: the first model is taken, ``--pick`` chooses another by a piece of its
path). Prints Markdown: one row per partition, the mean ± SD over partitions
beside the random baseline and the paper, accuracy and progress per action
(`standing` included), and how each model's run ended (``--run NAME=RUN_DIR``:
the run's ``history.jsonl``). ``--write DOC`` puts the same text between the
``<!-- partitions:begin -->`` and ``<!-- partitions:end -->`` lines of DOC
(``--section NAME``: the ``<!-- NAME:begin -->`` ones, so that a second
recipe's table can stand beside the first); ``--img DIR`` draws the confusion
matrix (partitions summed) and each partition's precision-margin curve there
(``NAME-confusion.png``, ``NAME-precision-margin.png``) and links them. ``--clean
NAME=REPORT`` adds the same models scored on copies of the held-out sessions
made without the simulator's sensor and transport effects (``scotti sim corpus
--effects none``, same seed): what those effects cost.

A model whose card (``NAME.card.json`` beside the graph) lists a held-out
subject among its training or validation subjects is refused: the figure
would not be a held-out one.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any

from card_training import training_block
from common import (
    ROOT,
    ExperimentError,
    fmt,
    from_root,
    pairs,
    table,
    utc_now,
    write_section,
)
from tables_doc import METRICS, per_action, plot_confusion, plot_curves, table1

SECTION = "partitions"  # the doc's <!-- partitions:begin --> ... :end --> lines
BEGIN, END = f"<!-- {SECTION}:begin -->", f"<!-- {SECTION}:end -->"

FLAGS = ("unloaded", "out_of_range", "unfamiliar")


def load_report(path: Path, pick: str) -> dict[str, Any]:
    """One model's report from a ``scotti eval --json`` file."""
    value = json.loads(path.read_text())
    reports = value if isinstance(value, list) else [value]
    chosen = [r for r in reports if pick in str(r["model"]["path"])] if pick else reports[:1]
    if not chosen:
        raise ExperimentError(f"{path}: no model whose path contains {pick!r}")
    return chosen[0]


def report_of(value: Path | str) -> dict[str, Any]:
    """FILE, or FILE#PIECE: the model of FILE whose path contains PIECE (else its first)."""
    path, _, pick = str(value).partition("#")
    return load_report(Path(path), pick)


def check_held_out(name: str, report: dict[str, Any]) -> None:
    """Refuse a model that trained or validated on a subject it is scored on."""
    graph = ROOT / report["model"]["path"]
    card_path = graph.with_name(graph.name.removesuffix(".onnx") + ".card.json")
    if not card_path.is_file():
        return
    data = json.loads(card_path.read_text()).get("training_data")
    # A card may describe its data in words (the tiny test model: no training at all).
    seen = set(data.get("subjects", [])) if isinstance(data, dict) else set()
    overlap = sorted(seen & set(report["subjects"]))
    if overlap:
        model = from_root(report["model"]["path"])
        raise ExperimentError(
            f"{name}: {model} trained or validated on {', '.join(overlap)}, which it is scored on"
        )


def partition_rows(reports: dict[str, dict[str, Any]]) -> list[str]:
    header = ["partition", "model", "held out", "frames"]
    header += [c for _, c, _, _, _ in METRICS]
    header += [
        "random accuracy (%)",
        "random APP",
        "flagged (unloaded / out of range / unfamiliar)",
    ]
    rows = []
    for name, r in reports.items():
        m, rnd, ood = r["metrics"], r["random_baseline"], r.get("ood") or {}
        cells = [
            name,
            f"`{from_root(r['model']['path'])}`",
            ", ".join(s[-3:] for s in r["subjects"]),
        ]
        cells.append(str(m["frames"]))
        cells += [fmt([m[k]], d, s).split(" ")[0] for k, _, d, s, _ in METRICS]
        cells += [f"{100 * rnd['action_accuracy']:.2f}", f"{rnd['app']:.4f}"]
        cells.append(" / ".join(f"{100 * (ood.get(f) or 0):.2f} %" for f in FLAGS))
        rows.append(cells)
    return table(header, rows)


def run_lines(runs: dict[str, Path]) -> list[str]:
    lines = []
    for name, run_dir in runs.items():
        block = training_block(run_dir / "best.pt")
        if block is None:
            raise ExperimentError(f"--run {name}: {run_dir} has no history.jsonl")
        best = next(e for e in block["epochs"] if e["epoch"] == block["best_epoch"])
        v = best["val"]
        lines.append(
            f"- {name}: `{from_root(run_dir)}`, {len(block['epochs'])} epochs, "
            f"{block['train_seconds'] / 60:.0f} min of epochs; stopped: {block['status']}; "
            f"best epoch {block['best_epoch']} (validation loss {v['loss']:.3f}, accuracy "
            f"{100 * v['action_accuracy']:.1f} %, progress MSE {v['progress_mse']:.4f}, "
            f"APP {v['app']:.4f})"
        )
    return lines


def figures(
    reports: dict[str, dict[str, Any]], img: Path, doc_dir: Path, section: str = "partitions"
) -> list[str]:
    """The confusion matrix (partitions summed) and the precision-margin curves, as PNGs."""
    img.mkdir(parents=True, exist_ok=True)
    multi = list(reports.values())
    confusion = plot_confusion(multi, img, f"{section}-confusion.png", " (each partition's model)")
    curves = plot_curves(multi, img, f"{section}-precision-margin.png", list(reports))
    return [
        f"![confusion matrix, partitions summed]({_relative(confusion, doc_dir)})",
        "",
        f"![precision-margin curves, one per partition]({_relative(curves, doc_dir)})",
    ]


def _relative(path: Path, start: Path) -> str:
    return os.path.relpath(path.resolve(), start.resolve())


def check_clean(reports: dict[str, dict[str, Any]], clean: dict[str, dict[str, Any]]) -> None:
    """A clean report must score the same model on the same people as its partition's."""
    for name, report in clean.items():
        if name not in reports:
            raise ExperimentError(f"--clean {name}: no report of that partition")
        same_model = report["model"].get("sha256") == reports[name]["model"].get("sha256")
        if not same_model or report["subjects"] != reports[name]["subjects"]:
            raise ExperimentError(
                f"--clean {name}: not the partition's model on its held-out subjects"
            )


def markdown(
    reports: dict[str, dict[str, Any]],
    runs: dict[str, Path],
    command: str,
    pictures: list[str] | None = None,
    clean: dict[str, dict[str, Any]] | None = None,
) -> str:
    multi = list(reports.values())
    lines = [
        f"Written by `{command}` ({utc_now()}) from the `scotti eval --json` reports named",
        "there: each partition's own model, scored on that partition's held-out subjects",
        "through the daemon's streaming path.",
        "",
        *partition_rows(reports),
        "",
        f"Mean ± sample SD over the {len(multi)} partitions:",
        "",
        *table1(multi, list((clean or {}).values())),
        "",
        "Per action, pooled frames; figures are the mean ± SD over the partitions:",
        "",
        *per_action(multi),
    ]
    if pictures:
        lines += ["", *pictures]
    if runs:
        lines += ["", "How each model's training ended (validation subjects only):", ""]
        lines += run_lines(runs)
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python experiments/partition_table.py",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("reports", nargs="+", metavar="NAME=REPORT")
    parser.add_argument("--run", action="append", default=[], metavar="NAME=RUN_DIR")
    parser.add_argument("--pick", default="", help="the model whose path contains this")
    parser.add_argument("--write", type=Path, help="replace the marked section of this doc")
    parser.add_argument("--section", default=SECTION, help="which marked section of --write")
    parser.add_argument("--img", type=Path, help="draw the confusion matrix and curves here")
    parser.add_argument(
        "--clean",
        action="append",
        default=[],
        metavar="NAME=REPORT",
        help="the same model on clean copies of the held-out sessions (no sensor effects)",
    )
    args = parser.parse_args(argv)
    command = "python experiments/partition_table.py " + " ".join(
        argv if argv is not None else sys.argv[1:]
    )
    try:
        reports = {n: load_report(p, args.pick) for n, p in pairs(args.reports, "report").items()}
        for name, report in reports.items():
            check_held_out(name, report)
        doc_dir = args.write.parent if args.write else Path.cwd()
        pictures = figures(reports, args.img, doc_dir, args.section) if args.img else None
        clean = {n: load_report(p, args.pick) for n, p in pairs(args.clean, "--clean").items()}
        check_clean(reports, clean)
        text = markdown(reports, pairs(args.run, "--run"), command, pictures, clean)
        if args.write:
            write_section(args.write, text, args.section)
    except (ExperimentError, OSError, KeyError, ValueError) as exc:
        print(f"partition_table: {exc}", file=sys.stderr)
        return 1
    print(text, end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
