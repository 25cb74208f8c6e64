"""Side-by-side figures of training runs: the paper form against the streaming-native one.

``python experiments/streaming_native_accuracy.py paper=RUN_DIR streaming=RUN_DIR``

Reads each run directory ``scotti train`` wrote (history.jsonl, test.json when the
run ended on its epochs) and prints a markdown table: epochs, training seconds,
windows/s, the best epoch's validation figures and best.pt's test figures. The runs
docs/streaming-native.md reports were made by the commands written there.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

METRICS = ("mpjpe_mm", "mpjae_deg", "action_accuracy", "progress_mse", "app")
HEADER = (
    "| run | set | epoch | train s | windows/s | MPJPE mm | MPJAE deg | accuracy % "
    "| progress MSE | APP |"
)


def load(run: Path) -> tuple[list[dict[str, Any]], dict[str, Any] | None]:
    lines = (run / "history.jsonl").read_text().splitlines()
    history = [json.loads(line) for line in lines if line.strip()]
    test_path = run / "test.json"
    test = json.loads(test_path.read_text()) if test_path.is_file() else None
    return history, test


def cells(metrics: dict[str, Any]) -> str:
    m = {k: metrics.get(k) for k in METRICS}
    if any(v is None for v in m.values()):
        return "| " + " | ".join("-" for _ in METRICS) + " |"
    return (
        f"| {m['mpjpe_mm']:.1f} | {m['mpjae_deg']:.2f} | {100 * m['action_accuracy']:.2f} "
        f"| {m['progress_mse']:.4f} | {m['app']:.4f} |"
    )


def rows(name: str, run: Path) -> list[str]:
    history, test = load(run)
    with_val = [h for h in history if h.get("val")]
    seconds = sum(h.get("seconds", 0.0) for h in history)
    speed = sum(h.get("windows_per_s", 0.0) for h in history) / max(len(history), 1)
    out = []
    if with_val:
        best = min(with_val, key=lambda h: h["val"]["loss"])
        head = f"| {name} | validation (best) | {best['epoch']} | {seconds:.0f} | {speed:.1f} "
        out.append(head + cells(best["val"]))
    if test is not None:
        head = f"| {name} | test (best.pt) | {test.get('epoch')} | {seconds:.0f} | {speed:.1f} "
        out.append(head + cells(test["test"]))
    return out


def main(argv: Sequence[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    if not args or any("=" not in a for a in args):
        print("usage: streaming_native_accuracy.py NAME=RUN_DIR ...", file=sys.stderr)
        return 2
    print(HEADER)
    print("|---" * (HEADER.count("|") - 1) + "|")
    for arg in args:
        name, _, path = arg.partition("=")
        run = Path(path)
        if not (run / "history.jsonl").is_file():
            print(f"{run}: no history.jsonl (not a scotti train run directory)", file=sys.stderr)
            return 2
        print("\n".join(rows(name, run)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
