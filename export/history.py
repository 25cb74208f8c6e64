"""``scotti train-history RUN_DIR -o plot.png``: a run's history.jsonl drawn per epoch.

Four panels: training and validation loss (the best epoch and a plateau
marked), and the validation progress MSE, APP and action accuracy. This is
where a run shows that it has learnt what it can: the validation loss flat
while the training loss still falls. A PNG that exists is refused unless
``--force`` (redrawing a run that trained on). Needs matplotlib, not torch.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

from scotti.export.errors import ExportError
from scotti.firmware_protocol.overwrite import (
    FORCE_HELP,
    REFUSED,
    OutputExistsError,
    refuse_existing,
)


class HistoryError(ExportError):
    """A run directory or history file that cannot be drawn (one-line message)."""


def read_history(path: Path) -> list[dict[str, Any]]:
    """The epoch records of RUN_DIR/history.jsonl (or of that file named directly)."""
    file = path / "history.jsonl" if path.is_dir() else path
    try:
        lines = file.read_text().splitlines()
    except OSError as exc:
        msg = f"{file}: {exc.strerror or exc}"
        raise HistoryError(msg) from None
    records: list[dict[str, Any]] = []
    for number, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            msg = f"{file}:{number}: not a JSON line"
            raise HistoryError(msg) from None
        if not isinstance(record, dict) or not isinstance(record.get("epoch"), int):
            msg = f"{file}:{number}: not an epoch record (no integer 'epoch')"
            raise HistoryError(msg)
        records.append(record)
    if not records:
        msg = f"{file}: no epochs in the history"
        raise HistoryError(msg)
    return records


def _series(history: list[dict[str, Any]], key: str, val: bool = True) -> list[float]:
    values = []
    for record in history:
        value = (record.get("val") or {}).get(key) if val else record.get(key)
        values.append(float(value) if isinstance(value, int | float) else math.nan)
    return values


def plot_history(history: list[dict[str, Any]], out: Path, title: str) -> None:
    import matplotlib  # heavy: loaded only when drawing

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    epochs = [int(r["epoch"]) for r in history]
    fig, axes = plt.subplots(1, 4, figsize=(16, 3.8), constrained_layout=True)
    loss = axes[0]
    loss.plot(epochs, _series(history, "train_loss", val=False), "o-", label="train")
    loss.plot(epochs, _series(history, "loss"), "s-", label="validation")
    last = history[-1]
    best = last.get("best_epoch")
    if isinstance(best, int) and best > 0:
        loss.axvline(best, color="grey", linestyle=":", label=f"best epoch {best}")
    if last.get("status") == "plateau":
        loss.set_title(f"loss (plateau after epoch {epochs[-1]})")
    else:
        loss.set_title("loss")
    loss.legend()
    panels = (
        ("progress_mse", "validation progress MSE", "C2"),
        ("app", "validation APP", "C3"),
        ("action_accuracy", "validation action accuracy", "C4"),
    )
    for ax, (key, name, colour) in zip(axes[1:], panels, strict=True):
        ax.plot(epochs, _series(history, key), "o-", color=colour)
        ax.set_title(name)
    for ax in axes:
        ax.set_xlabel("epoch")
        ax.grid(alpha=0.3)
    fig.suptitle(title)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=100)
    plt.close(fig)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", type=Path, help="run directory (or its history.jsonl)")
    parser.add_argument(
        "-o",
        "--output",
        type=Path,
        default=None,
        help=f"PNG (default RUN/history.png; {REFUSED})",
    )
    parser.add_argument("--force", action="store_true", help=FORCE_HELP)


def run(args: argparse.Namespace) -> int:
    run_dir = args.run if args.run.is_dir() else args.run.parent
    out = args.output or run_dir / "history.png"
    try:
        refuse_existing([out], force=args.force)
        history = read_history(args.run)
    except (HistoryError, OutputExistsError) as exc:
        print(f"scotti train-history: {exc}", file=sys.stderr)
        return 2
    plot_history(history, out, f"{run_dir.name}: {len(history)} epochs")
    print(out)
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m scotti.export.history")
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
