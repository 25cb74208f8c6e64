"""The daemon's sessions run graphs with their subnormal weights set to 0, and touch
nothing else: the graph file, its hash and the process's float arithmetic stay as
they were."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
from onnx import helper, numpy_helper
from scotti.models.errors import ModelError
from scotti.models.graph_checks import open_session, sha256_of
from scotti.models.subnormal_weights import without_subnormal_weights

SUBNORMAL = 1e-39  # below float32's smallest normal number, 1.18e-38


def _probe(path: Path, w: list[float]) -> Path:
    """y = x * w: its output shows the weights onnxruntime was given."""
    weights = numpy_helper.from_array(np.array(w, np.float32), "w")
    graph = helper.make_graph(
        [helper.make_node("Mul", ["x", "w"], ["y"])],
        "probe",
        [helper.make_tensor_value_info("x", onnx.TensorProto.FLOAT, [len(w)])],
        [helper.make_tensor_value_info("y", onnx.TensorProto.FLOAT, [len(w)])],
        [weights],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 20)])
    model.ir_version = 9
    onnx.save(model, str(path))
    return path


def _run(session: ort.InferenceSession, n: int) -> np.ndarray:
    return np.asarray(session.run(None, {"x": np.ones(n, np.float32)})[0])


def test_subnormal_weights_run_as_zero_and_normal_ones_as_they_are(tmp_path: Path) -> None:
    w = [SUBNORMAL, -SUBNORMAL, 0.5, 1e-30]
    graph = _probe(tmp_path / "probe.onnx", w)
    sha = sha256_of(graph)
    as_is = _run(ort.InferenceSession(str(graph), providers=["CPUExecutionProvider"]), 4)
    assert as_is[0] != 0  # onnxruntime alone keeps subnormals: the check below can fail
    daemon = _run(open_session(graph, threads=1), 4)
    np.testing.assert_array_equal(daemon, np.array([0, 0, 0.5, 1e-30], np.float32))
    assert sha256_of(graph) == sha  # the file the daemon reports is not rewritten
    # No floating-point mode was switched for the process (onnxruntime's
    # set_denormal_as_zero would have been, on this thread).
    assert np.float32(SUBNORMAL) * np.float32(1.0) != 0
    assert 5e-324 * 1.0 != 0  # Python's own (double) subnormal


def test_a_graph_without_subnormal_weights_is_opened_from_its_file(tmp_path: Path) -> None:
    graph = _probe(tmp_path / "clean.onnx", [0.5, 0.0])
    assert without_subnormal_weights(graph) is None
    np.testing.assert_array_equal(_run(open_session(graph, threads=1), 2), [0.5, 0.0])
    zeroed = without_subnormal_weights(_probe(tmp_path / "sub.onnx", [SUBNORMAL, 0.5]))
    assert zeroed is not None
    assert zeroed[1] == 1


def test_an_unreadable_file_still_gets_the_runtimes_one_line_error(tmp_path: Path) -> None:
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"not a protobuf at all")
    assert without_subnormal_weights(bad) is None
    with pytest.raises(ModelError, match="is not a loadable ONNX model"):
        open_session(bad, threads=1)
