"""The model card: what a model is, what it was trained on, how its export was proven.

NAME.card.json holds the card embedded in each graph's ``scotti.card``
metadata plus what a file cannot say about itself (its size and sha256) and
the measured parity; NAME.card.md is the same for people.
"""

from __future__ import annotations

import hashlib
import json
import platform
from importlib import metadata as importlib_metadata
from pathlib import Path
from typing import Any

import torch
from scotti.export.parity import format_report


def tool_versions() -> dict[str, str]:
    versions = {"python": platform.python_version()}
    for dist in ("torch", "onnx", "onnxruntime", "onnxscript", "numpy", "scotti"):
        try:
            versions[dist] = importlib_metadata.version(dist)
        except importlib_metadata.PackageNotFoundError:
            versions[dist] = "absent"
    return versions


def file_entry(path: Path) -> dict[str, Any]:
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    return {"file": path.name, "bytes": path.stat().st_size, "sha256": digest}


def card_markdown(card: dict[str, Any]) -> str:
    """The card for people: what the model is, what it was trained on, how it was proven."""
    cfg = card["config"]
    lines = [
        f"# Model card: {card['name']}",
        "",
        f"{card['model']}. Contract version {card['contract_version']}; "
        f"precision {card['precision']}; {card['parameters']:,} parameters; "
        f"exported {card['exported_utc']}.",
        "",
        f"Input: raw taxel counts, window T = {cfg['window']} frames of "
        f"{cfg['rows']} x {2 * cfg['cols']} (left | right). Normalisation inside the graph: "
        f"`{card['normalisation']}`. Timing: {card['timing']}.",
        "",
        "## Configuration",
        "",
        "| key | value |",
        "|---|---|",
        *(f"| {k} | {v} |" for k, v in cfg.items()),
        "",
        "## Training data",
        "",
        _block(card.get("training_data")),
        "",
        "## Metrics",
        "",
        _block(card.get("metrics")) + (f" (epoch {card['epoch']})" if card.get("epoch") else ""),
        "",
        "## Files",
        "",
        "| graph | file | bytes | sha256 |",
        "|---|---|---|---|",
        *(
            f"| {k} | {v['file']} | {v['bytes']:,} | `{v['sha256']}` |"
            for k, v in card["files"].items()
        ),
        "",
        "## Proof (onnxruntime against torch, max abs difference)",
        "",
        f"Tolerance: atol {card['parity']['tolerance']['atol']:g}, "
        f"rtol {card['parity']['tolerance']['rtol']:g}; hard inputs included.",
        "",
        *(f"- {line}" for line in format_report(card["parity"]["max_abs_diff"])),
    ]
    if card.get("int8_drift_max_abs"):
        lines += ["", "## int8 drift against fp32 (measured, not bounded)", ""]
        lines += [f"- {line}" for line in format_report(card["int8_drift_max_abs"])]
    lines += ["", "## Tools", "", ", ".join(f"{k} {v}" for k, v in card["tools"].items()), ""]
    return "\n".join(lines)


def _block(value: Any) -> str:
    if value is None:
        return "Not recorded in the checkpoint."
    if isinstance(value, str):
        return value
    return "```json\n" + json.dumps(value, indent=2, sort_keys=True, default=jsonable) + "\n```"


def jsonable(value: Any) -> Any:
    """Checkpoint extras may hold tensors (weights_only allows them): as lists."""
    if isinstance(value, torch.Tensor):
        return value.tolist()
    return str(value)
