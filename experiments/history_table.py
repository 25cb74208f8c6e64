"""Validation epoch by epoch for one or more training runs, as a Markdown table.

    python experiments/history_table.py p1=runs/v12ema-p1-xt0.03-more \\
        p2=runs/v12ema-p2-xt0.03-more [--write docs/evaluation.md --section v12-epochs]

Each NAME=RUN_DIR is a ``scotti train`` output folder; its ``history.jsonl``
(one record per finished epoch) gives the training loss and the validation
figures. The epoch with the lowest validation loss, the one ``best.pt`` holds,
is in bold. Runs that validate on different people are listed one below the
other: compare down a run's epochs, not across runs. ``--write DOC`` puts the
table between the ``<!-- SECTION:begin -->`` and ``<!-- SECTION:end -->``
lines of DOC.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from common import ExperimentError, pairs, table, utc_now, write_section

HEADER = (
    "run", "epoch", "train loss", "val loss", "val accuracy", "val progress MSE", "val APP",
    "val MPJPE (mm)",
)  # fmt: skip


def epochs_of(run_dir: Path) -> list[dict[str, Any]]:
    """The run's epoch records in order; refuses a run with none (or a broken line)."""
    path = run_dir / "history.jsonl"
    if not path.is_file():
        raise ExperimentError(f"{run_dir}: no history.jsonl (not a scotti train run?)")
    records = []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
            records.append(
                record | {"epoch": int(record["epoch"]), "train_loss": float(record["train_loss"])}
            )
        except (ValueError, KeyError, TypeError) as exc:
            raise ExperimentError(f"{path}:{number}: not an epoch record ({exc})") from exc
    if not records:
        raise ExperimentError(f"{path}: no finished epoch yet")
    return records


def rows_of(name: str, records: list[dict[str, Any]]) -> list[list[str]]:
    losses = [r.get("val", {}).get("loss", float("inf")) for r in records]
    best = losses.index(min(losses))
    rows = []
    for k, record in enumerate(records):
        val = record.get("val", {})
        loss = f"{val['loss']:.3f}" if "loss" in val else "-"
        rows.append(
            [
                name,
                str(record["epoch"]),
                f"{record['train_loss']:.3f}",
                f"**{loss}**" if k == best and "loss" in val else loss,
                f"{100 * val['action_accuracy']:.1f} %" if "action_accuracy" in val else "-",
                f"{val['progress_mse']:.4f}" if "progress_mse" in val else "-",
                f"{val['app']:.3f}" if "app" in val else "-",
                f"{val['mpjpe_mm']:.1f}" if "mpjpe_mm" in val else "-",
            ]
        )
    return rows


def markdown(runs: dict[str, Path], command: str) -> str:
    rows = []
    for name, run_dir in runs.items():
        rows += rows_of(name, epochs_of(run_dir))
    lines = [f"Written by `{command}` ({utc_now()}) from each run's history.jsonl.", ""]
    return "\n".join([*lines, *table(HEADER, rows)]) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python experiments/history_table.py",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("runs", nargs="+", metavar="NAME=RUN_DIR")
    parser.add_argument("--write", type=Path, help="replace the marked section of this doc")
    parser.add_argument("--section", default="epochs", help="which marked section of --write")
    args = parser.parse_args(argv)
    command = "python experiments/history_table.py " + " ".join(
        argv if argv is not None else sys.argv[1:]
    )
    try:
        text = markdown(pairs(args.runs, "run"), command)
        if args.write:
            write_section(args.write, text, args.section)
    except (ExperimentError, OSError) as exc:
        print(f"history_table: {exc}", file=sys.stderr)
        return 1
    print(text, end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
