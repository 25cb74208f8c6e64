"""The model card's training section: how the run went, epoch by epoch.

Read from the run directory next to the shipped checkpoint (``history.jsonl``,
written by ``scotti train``): per epoch the training loss, the validation
figures and whether the run stopped on a plateau, so a reader of the card sees
where validation stopped improving rather than taking "trained to its plateau"
on trust. ``command.txt`` in the run directory, when there, is quoted too, and
the recipe (the ``scotti train`` options the checkpoint recorded: schedule,
loss weights, augmentation), so that two cards say how their models differ.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from common import table

VAL_KEYS = ("loss", "mpjpe_mm", "action_accuracy", "progress_mse", "app")
# The options of export/train.py's TrainOptions a reader needs to train the same model.
RECIPE_KEYS = (
    "epochs", "batch", "stride", "lr", "weight_decay", "loss_weights", "max_shift",
    "max_crosstalk", "ema", "precision", "patience", "seed",
)  # fmt: skip
# Options that came later: a checkpoint without them was trained without them (0 = off).
LATER_KEYS = ("max_crosstalk", "ema")


def recipe_of(checkpoint: Path) -> dict[str, Any] | None:
    """The training options saved in the checkpoint (None for one that has none)."""
    import torch  # the [train] extra, where the shipping script runs

    try:
        raw = torch.load(checkpoint, map_location="cpu", weights_only=True)
    except Exception:  # torch raises many types for a bad file; the card goes without
        return None
    options = raw.get("options") if isinstance(raw, dict) else None
    if not isinstance(options, dict):
        return None
    return {k: options.get(k, 0.0 if k in LATER_KEYS else None) for k in RECIPE_KEYS}


def training_block(checkpoint: Path) -> dict[str, Any] | None:
    """The run's history beside ``checkpoint`` (None when it has none)."""
    run = checkpoint.parent
    history = run / "history.jsonl"
    if not history.is_file():
        return None
    records = [json.loads(line) for line in history.read_text().splitlines() if line.strip()]
    if not records:
        return None
    epochs = [
        {
            "epoch": int(r["epoch"]),
            "train_loss": r["train_loss"],
            "seconds": r.get("seconds"),
            "val": {k: (r.get("val") or {}).get(k) for k in VAL_KEYS},
        }
        for r in records
    ]
    last = records[-1]
    status = last.get("status")
    if status is None and last.get("lr") == 0.0:
        # Runs from before scotti train wrote "epochs done": the cosine reaches 0 only
        # at the last step of the last epoch.
        status = "epochs done"
    command = run / "command.txt"
    return {
        "epochs": epochs,
        "best_epoch": last.get("best_epoch"),
        # A run whose last record has no status ended without a decision: its time
        # budget (--max-minutes) ran out first (or it is still going).
        "status": status
        or f"time budget (--max-minutes), {last.get('stale_epochs', 0)} epochs since the best",
        "train_seconds": sum(float(e["seconds"] or 0) for e in epochs),
        "command": command.read_text().strip() if command.is_file() else None,
        "recipe": recipe_of(checkpoint) if checkpoint.is_file() else None,
    }


def training_markdown(block: dict[str, Any] | None) -> list[str]:
    if not block:
        return []
    lines = [
        "",
        "## Training run (validation per epoch)",
        "",
        f"Stopped: {block['status']} after {len(block['epochs'])} epochs; best epoch "
        f"{block['best_epoch']} (the shipped weights); "
        f"{block['train_seconds'] / 60:.0f} min of training on this CPU "
        "(time of the epochs after any resume).",
        "",
    ]
    rows = []
    for e in block["epochs"]:
        v = e["val"]
        if v["loss"] is None:
            rows.append([str(e["epoch"]), f"{e['train_loss']:.4f}", *["-"] * 5])
            continue
        rows.append(
            [
                str(e["epoch"]),
                f"{e['train_loss']:.4f}",
                f"{v['loss']:.4f}",
                f"{v['mpjpe_mm']:.1f}",
                f"{100 * v['action_accuracy']:.2f} %",
                f"{v['progress_mse']:.4f}",
                f"{v['app']:.4f}",
            ]
        )
    header = ["epoch", "train loss", "val loss", "val MPJPE (mm)", "val accuracy"]
    lines += table([*header, "val progress MSE", "val APP"], rows)
    if block.get("recipe"):
        lines += ["", f"Recipe (`scotti train` options): {recipe_line(block['recipe'])}."]
    if block.get("command"):
        command = block["command"]
        # command.txt holds scotti train's options, or a whole command line (train_wide.sh's).
        whole = command.startswith("scotti ") or "scripts/" in command
        shown = command if whole else f"scotti train {command}"
        lines += ["", "```", shown, "```"]
    return lines


def recipe_line(recipe: dict[str, Any]) -> str:
    words = []
    for key, value in recipe.items():
        if value is None:
            continue
        if isinstance(value, dict):  # the loss weights
            value = ", ".join(f"{k} {v:g}" for k, v in value.items())
            words.append(f"{key} ({value})")
        else:
            words.append(f"{key} {value:g}" if isinstance(value, float) else f"{key} {value}")
    return "; ".join(words)
