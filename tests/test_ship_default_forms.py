"""The release step ships either form the daemon serves: scripts/ship_default.py on a
streaming-native export, and experiments/measure.py timing each form's step the way the
daemon calls it (the paper form's step on cached embeddings, the streaming-native
form's on warm key/value caches)."""

from __future__ import annotations

import hashlib
import json
import math
import sys
from pathlib import Path

import pytest

pytest.importorskip("torch")
from scotti.models.kv_streaming import KvStepRuntime, open_step_model

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "experiments"))
sys.path.insert(0, str(ROOT / "scripts"))
import measure  # noqa: E402
import ship_default  # noqa: E402

pytestmark = pytest.mark.torch

LATENCY_KEYS = {"step_median_ms", "step_p99_ms", "window_median_ms", "window_p99_ms"}


@pytest.mark.parametrize("form", ["paper", "kv"])
def test_measure_times_either_form_and_counts_its_flops(
    form: str, kv_model: Path, tiny_model_path: Path
) -> None:
    model = kv_model if form == "kv" else tiny_model_path
    got = measure.describe([model], [1], steps=5)[str(model)]
    latency = got["latency"]["1"]
    assert set(latency) == LATENCY_KEYS
    assert all(math.isfinite(v) and v > 0 for v in latency.values())
    assert latency["step_p99_ms"] >= latency["step_median_ms"]
    # One new frame costs less arithmetic than recomputing the whole window.
    assert 0 < got["step_flops"] < got["window_flops"]


def test_a_streaming_native_export_ships_with_its_card_embedded(
    kv_model: Path, tmp_path: Path
) -> None:
    out = tmp_path / "models"
    code = ship_default.main([str(kv_model), "--data", "two tiny people", "--out-dir", str(out)])
    assert code == 0
    step = out / "scotti-default.onnx"
    shipped = open_step_model(step)  # what the daemon opens
    assert isinstance(shipped, KvStepRuntime)
    card = json.loads((out / "scotti-default.card.json").read_text())
    assert card["files"]["step"]["sha256"] == hashlib.sha256(step.read_bytes()).hexdigest()
    assert card["shipped_data"] == "two tiny people"
    assert shipped.card["shipped_data"] == "two tiny people"  # embedded, for the info topic
    assert set(card["latency"]["by_threads"]["1"]) == LATENCY_KEYS
    assert "warm key/value caches" in (out / "scotti-default.card.md").read_text()
    assert open_step_model(out / "scotti-default.window.onnx").graph == "window"
