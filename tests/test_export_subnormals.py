"""Subnormal weights: ``scotti export`` writes them as 0 (export/subnormals.py)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("torch")
import onnx
import torch
from onnx import numpy_helper
from scotti.export import export_cli
from scotti.export.model import Scotti, ScottiConfig
from scotti.export.subnormals import zero_subnormal_weights

pytestmark = pytest.mark.torch

SUBNORMAL = 1e-39  # below float32's smallest normal number, 1.18e-38
TINY = np.finfo(np.float32).tiny
CFG = ScottiConfig(window=8, embed_dim=16, layers=1, heads=2, conv_channels=(3, 4), head_hidden=8)


def _subnormal_model(count: int) -> Scotti:
    torch.manual_seed(3)
    model = Scotti(CFG).eval()
    with torch.no_grad():
        weight = next(p for name, p in model.named_parameters() if name.endswith("proj.weight"))
        weight.view(-1)[:count] = SUBNORMAL  # as weight decay leaves the unused taxels' weights
    return model


def _subnormals_in(graph: Path) -> int:
    total = 0
    for init in onnx.load(str(graph)).graph.initializer:
        weights = numpy_helper.to_array(init)
        if weights.dtype == np.float32:
            total += int(((weights != 0) & (np.abs(weights) < TINY)).sum())
    return total


def test_zero_subnormal_weights_counts_and_zeroes_only_them() -> None:
    model = _subnormal_model(50)
    before = {k: v.clone() for k, v in model.state_dict().items()}
    assert zero_subnormal_weights(model) == 50
    for name, value in model.state_dict().items():
        changed = value != before[name]
        assert bool((before[name][changed].abs() < TINY).all()), name  # nothing normal moved
        assert not bool(((value != 0) & (value.abs() < TINY)).any()), name
    assert zero_subnormal_weights(model) == 0


def test_export_writes_subnormal_weights_as_zero(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    ckpt = tmp_path / "run.pt"
    torch.save({"config": CFG.to_dict(), "model": _subnormal_model(40).state_dict()}, ckpt)
    out = tmp_path / "run.onnx"
    args = export_cli.argparse.ArgumentParser()
    export_cli.add_arguments(args)
    assert export_cli.run(args.parse_args([str(ckpt), "-o", str(out)])) == 0
    assert "40 subnormal weights written as 0" in capsys.readouterr().out
    assert _subnormals_in(out) == 0
    assert _subnormals_in(out.with_name("run.window.onnx")) == 0
    assert json.loads(out.with_name("run.card.json").read_text())["subnormal_weights_zeroed"] == 40
