"""The test subjects' figures, once, at the end of a run: ``RUN_DIR/test.json``.

Training never looks at the test subjects (best.pt and the plateau come from
the validation set). When a run ends (its epochs done, or its plateau), the
weights of best.pt are evaluated on the test set and written to their own
file, apart from history.jsonl, so that no figure of it can steer training.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import torch
from scotti.export.checkpoint import load_checkpoint
from scotti.export.evaluate import evaluate
from scotti.export.losses import LossWeights
from scotti.export.model import Scotti, ScottiConfig
from scotti.export.windows import WindowDataset


def write_test_report(
    run_dir: Path,
    test_set: WindowDataset,
    *,
    stride: int,
    weights: LossWeights,
    device: torch.device,
) -> dict[str, Any] | None:
    """Evaluate best.pt on ``test_set`` into RUN_DIR/test.json; None without either."""
    best = run_dir / "best.pt"
    if test_set.count(stride) == 0 or not best.is_file():
        return None
    ckpt = load_checkpoint(best)
    model = Scotti(ScottiConfig.from_dict(ckpt["config"]))
    model.load_state_dict(ckpt["model"])
    metrics = evaluate(model.to(device), test_set, stride, weights)
    history = ckpt.get("history") or [{}]
    report = {
        "checkpoint": "best.pt",
        "epoch": history[-1].get("epoch"),
        "test_subjects": ckpt.get("training_data", {}).get("split", {}).get("test_subjects"),
        "stride": stride,
        "test": metrics,
    }
    (run_dir / "test.json").write_text(json.dumps(report, indent=1) + "\n")
    return report
