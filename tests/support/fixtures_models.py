"""The committed tiny SCOTTI model (``python -m scotti.export.make_tiny tests/data/tiny``).

Random but seeded weights, T = 40, E = 32: real ONNX graphs that load and run
in milliseconds, with the contract's names and metadata. No torch needed.
"""

from __future__ import annotations

from pathlib import Path

import pytest

TINY_DIR = Path(__file__).resolve().parent.parent / "data" / "tiny"
TINY_STEP = TINY_DIR / "scotti-tiny.onnx"  # the streaming step graph (what the daemon loads)
TINY_WINDOW = TINY_DIR / "scotti-tiny.window.onnx"  # B windows of T frames
TINY_CHECKPOINT = TINY_DIR / "scotti-tiny.pt"  # the torch checkpoint both were exported from


@pytest.fixture(scope="session")
def tiny_model_path() -> Path:
    """Path of the committed tiny step graph (tests/data/tiny/scotti-tiny.onnx)."""
    assert TINY_STEP.is_file(), f"missing {TINY_STEP}: run python -m scotti.export.make_tiny"
    return TINY_STEP


@pytest.fixture(scope="session")
def tiny_window_model_path() -> Path:
    """Path of the committed tiny window graph (tests/data/tiny/scotti-tiny.window.onnx)."""
    assert TINY_WINDOW.is_file(), f"missing {TINY_WINDOW}: run python -m scotti.export.make_tiny"
    return TINY_WINDOW


# The initializer of the action head's last bias in the exported graph (one logit per action).
ACTION_BIAS = "model.action_head.3.bias"
TINY_V1_STEP = TINY_DIR.parent / "contract-v1" / "scotti-tiny.onnx"  # exported before standing


def always_standing(source: Path, out: Path, margin: float = 50.0) -> Path:
    """The tiny graph with its ``standing`` logit raised by ``margin``: a real model
    that says standing on any input (its progress head still outputs numbers)."""
    import onnx
    from onnx import numpy_helper
    from scotti.models.contract import NUM_ACTIONS, STANDING

    model = onnx.load(str(source))
    bias = next(t for t in model.graph.initializer if t.name == ACTION_BIAS)
    values = numpy_helper.to_array(bias).copy()
    assert values.shape == (NUM_ACTIONS,), values.shape
    values[STANDING] += margin
    bias.CopyFrom(numpy_helper.from_array(values, ACTION_BIAS))
    onnx.save(model, str(out))
    return out


@pytest.fixture(scope="session")
def standing_model_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A step graph that always says standing (see ``always_standing``)."""
    out = tmp_path_factory.mktemp("standing") / "scotti-standing.onnx"
    return always_standing(TINY_STEP, out)


@pytest.fixture(scope="session")
def kv_model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny streaming-native export (T = 40, E = 32, 2 layers: S = 5, receptive field
    118 frames), made once per run; needs torch (tests that use it are torch tests)."""
    pytest.importorskip("torch")
    from scotti.export.model import Scotti
    from scotti.export.onnx_export import Checkpoint, export_model

    from tests.test_export_streaming_native import TINY_KV, spread

    out = tmp_path_factory.mktemp("kv-model") / "kv.onnx"
    export_model(Checkpoint(model=spread(Scotti(TINY_KV), 4)), out)
    return out
