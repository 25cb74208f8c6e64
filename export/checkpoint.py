"""Checkpoint files: one torch.save'd dict of plain values and tensors, written atomically.

Only tensors, numbers, strings, lists and dicts go in, so ``torch.load`` with
``weights_only=True`` reads it back: a checkpoint never runs code on load.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Any

import torch
from scotti.export.errors import ExportError


class CheckpointError(ExportError):
    """A checkpoint that cannot be read (one-line message)."""


def save_checkpoint(ckpt: dict[str, Any], path: Path) -> None:
    """Write ``ckpt`` to ``path``; a run killed meanwhile leaves the old file intact."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            torch.save(ckpt, f)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def load_checkpoint(path: Path | str) -> dict[str, Any]:
    """Read a checkpoint written by ``save_checkpoint``; CheckpointError on any problem."""
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except FileNotFoundError:
        msg = f"{path}: no such checkpoint"
        raise CheckpointError(msg) from None
    except Exception as exc:  # torch raises many kinds for a damaged or foreign file
        msg = f"{path}: not a readable checkpoint ({type(exc).__name__})"
        raise CheckpointError(msg) from None
    if not isinstance(ckpt, dict) or not {"config", "model"} <= set(ckpt):
        msg = f"{path}: not a SCOTTI checkpoint (no config/model)"
        raise CheckpointError(msg)
    return ckpt
