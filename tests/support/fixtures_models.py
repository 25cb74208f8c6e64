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
