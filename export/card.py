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
    lines += ood_markdown(card.get("ood"))
    if card.get("int8_ood"):
        int8 = card["int8_ood"]
        lines += [
            "",
            "The int8 graphs carry statistics of their own pooled vectors (int8 moves them): "
            f"threshold **{int8['threshold']:.2f}**, flagging {100 * int8['held_out_flagged']:.2f} "
            f"% of the held-out windows and {100 * int8['train_flagged']:.2f} % of the training "
            "windows.",
        ]
    lines += progress_markdown(card.get("progress_calibration"))
    lines += ["", "## Tools", "", ", ".join(f"{k} {v}" for k, v in card["tools"].items()), ""]
    return "\n".join(lines)


def progress_markdown(progress: dict[str, Any] | None) -> list[str]:
    """The card's section on the progress calibration (models/progress_calibration.py)."""
    lines = ["", "## Progress calibration", ""]
    if not progress or not progress.get("calibrated"):
        why = (progress or {}).get("reason", "export --calibrate, or scotti calibrate")
        return [*lines, f"None: the progress head's output as it is ({why})."]
    return [
        *lines,
        f"A monotone map per predicted action ({progress['method']}) for "
        f"{', '.join(progress['frames'])}, fitted on {progress['windows']} windows of the "
        f"held-out subjects {', '.join(progress['fitted_on'])}: progress MSE "
        f"{progress['mse_before']:.4f} -> {progress['mse_after']:.4f} on them.",
    ]


def _action_means_lines(actions: dict[str, dict[str, Any]] | None) -> list[str]:
    """Each action's mean and threshold: of how many training windows, from how many
    held-out windows the model called that action."""
    if not actions:
        return []
    rows = [
        f"| {name} | {a['train_windows']} | {a['held_out_windows']} | {a['threshold']:.2f} |"
        for name, a in actions.items()
    ]
    return [
        "",
        "The score is the distance to the mean of the action the model calls the window, "
        "over that action's threshold (the percentile above of the distances of the "
        "held-out windows called it; with fewer than 20 such windows, the nearest mean's); "
        "above 1 is unfamiliar.",
        "",
        "| action | training windows (mean) | held-out windows (threshold) | threshold |",
        "|---|---:|---:|---:|",
        *rows,
    ]


def ood_markdown(ood: dict[str, Any] | None) -> list[str]:
    """The card's section on what the model does not know (flags, statistics, threshold)."""
    lines = ["", "## What it does not know (OOD flags)", ""]
    if not ood or not ood.get("calibrated"):
        return [*lines, "Not calibrated: the `unfamiliar` score is null (export --calibrate)."]
    checks = ood.get("input_checks", {})
    held, train = ood["held_out_score_percentiles"], ood["train_score_percentiles"]
    lines += [
        f"`unfamiliar`: {ood['method']} (E={ood['dim']}, shrinkage {ood['shrinkage']:.4f}), "
        f"statistics of {ood['train_windows']} windows of the training subjects "
        f"({', '.join(ood['train_subjects'])}){_drawn(ood.get('windows_drawn'))}; "
        f"threshold **{ood['threshold']:.2f}** "
        + ("on the score, each action's own below, from the " if ood.get("actions") else "= the ")
        + f"{ood['threshold_percentile']:g}th percentile over {ood['held_out_windows']} windows "
        f"of the held-out ({ood['held_out_split']}) subjects "
        f"({', '.join(ood['held_out_subjects'])}).",
        *_action_means_lines(ood.get("actions")),
        "",
        "| score percentile | 50 | 90 | 99 | 99.9 | flagged |",
        "|---|---|---|---|---|---|",
        "| training windows | "
        + " | ".join(f"{train[k]:.2f}" for k in ("50.0", "90.0", "99.0", "99.9"))
        + f" | {100 * ood['train_flagged']:.2f} % |",
        "| held-out windows | "
        + " | ".join(f"{held[k]:.2f}" for k in ("50.0", "90.0", "99.0", "99.9"))
        + f" | {100 * ood['held_out_flagged']:.2f} % |",
        "",
        f"`unloaded`: both feet under {checks.get('unloaded_force_n')} N (nominal) for "
        f"{checks.get('unloaded_frames')} frames. `out_of_range`: "
        f"{checks.get('out_of_range_frames')} frames of a window with load outside the "
        f"outline (> {checks.get('outside_share_max')}), "
        f"a quarter of a foot at the rail, one taxel holding > {checks.get('peak_share_max')} of "
        f"a foot, more than {checks.get('force_max_n')} N, or one foot under "
        f"{checks.get('foot_empty_n')} N for the whole window. On these windows: training "
        f"{_shares(ood.get('input_checks_on_train'))}; held out "
        f"{_shares(ood.get('input_checks_on_held_out'))}. Figures: docs/ood.md.",
    ]
    return lines


def _drawn(drawn: dict[str, Any] | None) -> str:
    """How both sides' windows were drawn (export/calibration_draws.py), if not as recorded."""
    if not drawn or drawn.get("as_recorded", True):
        return ""
    low, high = drawn["tempo_range"]
    extra = ""
    if drawn.get("tempo_extra"):
        extra_low, extra_high = drawn["tempo_extra_range"]
        extra = f" and {100 * drawn['tempo_extra']:g} % at {extra_low:g}-{extra_high:g}"
    return (
        f", both sides drawn as training drew them ({100 * drawn['sensor_transfer']:g} % "
        f"through foreign insoles, {100 * drawn['tempo_stretch']:g} % at tempi "
        f"{low:g}-{high:g}{extra})"
    )


def _shares(shares: dict[str, float] | None) -> str:
    if not shares:
        return "not measured"
    return ", ".join(f"{k} {100 * v:.2f} %" for k, v in sorted(shares.items()))


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
