"""Subnormal weights of an ONNX graph, set to zero before onnxruntime sees them.

Weight decay leaves the weights no gradient reaches subnormal (below 1.2e-38 in
float32), and x86 multiplies subnormals through a microcode assist: a graph with
26,351 of them took 26 ms a window call against 2.0 ms with them zeroed, its step
2.3x (``python experiments/subnormal_cost.py``; no output moved). ``scotti export``
writes them as 0; this covers graphs exported elsewhere.

Why not onnxruntime's ``session.set_denormal_as_zero``: with one intra-op
thread the graph runs on the caller's thread, so the option only helps by
switching flush-to-zero on for the thread that opens the first session, once
per process, and for every thread started after it. That changes Python's own
float arithmetic for the whole daemon (the test suite's Hypothesis refused to
run under it). Zeroing the weights is local to the graph.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
from onnx import numpy_helper

_SMALLEST_NORMAL = np.finfo(np.float32).tiny


def without_subnormal_weights(path: Path) -> tuple[bytes, int] | None:
    """The graph at ``path`` serialised with its subnormal float32 weights set to 0, and
    how many there were; None when it has none (or onnx cannot read it: onnxruntime
    then gives its own error)."""
    try:
        model = onnx.load(str(path))
    except Exception:  # onnx raises protobuf's DecodeError and others for a bad file
        return None
    zeroed = 0
    for init in model.graph.initializer:
        if init.data_type != onnx.TensorProto.FLOAT:
            continue
        weights = numpy_helper.to_array(init)
        subnormal = (weights != 0) & (np.abs(weights) < _SMALLEST_NORMAL)
        if subnormal.any():
            zeroed += int(subnormal.sum())
            init.CopyFrom(numpy_helper.from_array(np.where(subnormal, 0, weights), init.name))
    return (model.SerializeToString(), zeroed) if zeroed else None
