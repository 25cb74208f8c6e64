"""int8 copies of an exported model (``export/quantize.py``): both graphs, the metadata
kept, the names ``scotti eval`` pairs; a missing graph is one line."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import onnx
import pytest
from scotti.export.quantize import QUANTIZED_OPS, int8_copies, main
from scotti.models.runtime import ScottiRuntime, load_pair


def test_int8_copies_of_both_graphs_load_and_stay_close(
    tmp_path: Path, tiny_model_path: Path
) -> None:
    step, window = int8_copies(tiny_model_path, tmp_path / "int8")
    assert (step.name, window.name) == ("scotti-tiny.int8.onnx", "scotti-tiny.int8.window.onnx")
    # scotti eval --every K finds the int8 window graph beside the int8 step graph.
    int8_step, int8_window = load_pair(step)
    assert int8_window.path == window
    for src, dst in (
        (tiny_model_path, step),
        (tiny_model_path.with_suffix(".window.onnx"), window),
    ):
        kept = {p.key: p.value for p in onnx.load(str(src)).metadata_props}
        assert {p.key: p.value for p in onnx.load(str(dst)).metadata_props} == kept
        ops = {n.op_type for n in onnx.load(str(dst)).graph.node}
        assert (
            "DynamicQuantizeLinear" in ops
            or "DynamicQuantizeMatMul" in ops
            or any("Integer" in op for op in ops)
        ), ops
        assert not (ops & set(QUANTIZED_OPS) - {"MatMul"}), ops  # no Gemm left in fp32
        assert dst.stat().st_size < src.stat().st_size
    fp32 = ScottiRuntime(tiny_model_path)
    rng = np.random.default_rng(0)
    frames = rng.integers(0, 1500, (4, *fp32.frame_shape)).astype(np.float32)
    past = rng.normal(size=(4, fp32.window - 1, fp32.embed_dim)).astype(np.float32)
    a, b = fp32.run_steps(frames, past), int8_step.run_steps(frames, past)
    assert b.pose.shape == a.pose.shape
    assert not np.array_equal(a.pose, b.pose)  # quantized: not the same graph
    # Weights to 8 bits: within a few percent of the fp32 graph's outputs.
    for got, want in ((b.embedding, a.embedding), (b.pose, a.pose)):
        assert np.abs(got - want).max() < 0.05 * np.abs(want).max()


def test_a_missing_window_graph_is_one_line(
    tmp_path: Path, tiny_model_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    alone = tmp_path / "alone.onnx"
    shutil.copy(tiny_model_path, alone)
    assert main([str(alone), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "alone.window.onnx: no such graph" in err
    assert err.count("\n") == 1
    assert not (tmp_path / "out" / "alone.int8.onnx").exists()


def test_cli_writes_both_copies(
    tmp_path: Path, tiny_model_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main([str(tiny_model_path), "-o", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert out.count("wrote ") == 2
    assert (tmp_path / "scotti-tiny.int8.window.onnx").is_file()
