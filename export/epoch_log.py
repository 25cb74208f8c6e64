"""What an epoch's end says: its log lines and the run's history.jsonl.

The trainer (export/train.py) builds an epoch's record (training loss,
validation, plateau, watched files); this module only tells it: one line
for the epoch, one per watched file, one for a plateau, and the whole
history rewritten, so a run's file always holds every epoch so far.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

from scotti.export.watch import watch_line

# The trainer's logger: the epoch's lines read as the run's, and callers that
# listen to scotti.export.train (tests, the CLI) hear them.
log = logging.getLogger("scotti.export.train")


def log_epoch(record: dict[str, Any], best_loss: float, min_delta: float) -> None:
    """The epoch's line, each watched file's, and the plateau's when it was reached."""
    val = record.get("val") or {}
    log.info(
        "epoch %d: loss %.4f, %.1f windows/s%s",
        record["epoch"],
        record["train_loss"],
        record["windows_per_s"],
        "".join(f", val {k} {v:.4g}" for k, v in val.items() if isinstance(v, float)),
    )
    for name, scores in record.get("watch", {}).items():
        log.info("%s", watch_line(name, scores))
    if record.get("status") == "plateau":
        log.info(
            "plateau: validation loss no better by %g for %d epochs; best epoch %d (%.4g)",
            min_delta,
            record["stale_epochs"],
            record["best_epoch"],
            best_loss,
        )


def write_history(run_dir: Path, history: list[dict[str, Any]]) -> None:
    """RUN/history.jsonl: one line per epoch, the whole history each time."""
    with (run_dir / "history.jsonl").open("w") as f:
        f.writelines(json.dumps(r) + "\n" for r in history)
