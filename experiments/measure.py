"""Per-frame latency, FLOPs and size of exported models.

    python experiments/measure.py MODEL.onnx [MODEL.onnx ...] [--steps 400] [--threads 1 2]

Latency: the daemon's own call, ``ScottiRuntime.step`` (one new frame + the
cached embeddings, batch 1; for the streaming-native form one ``KvStepRuntime``
step on warm key/value caches, the graph's own rows, and its result row), timed
per call after a warm-up; and, for the
comparison, one call of the window graph over all T frames (what recomputing
the whole window every frame would cost). Models take turns call by call, so
that load from other processes on a shared machine hits them alike.
FLOPs: counted from the ONNX graph (Conv, MatMul, Gemm multiply-adds x 2,
shapes from onnx shape inference at batch 1); the rest (softmax, norms,
activations) is a few percent and left out.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import onnx
from any_window import with_window
from onnx import shape_inference
from scotti.daemon.tools.step_costs import step_inputs, step_rows
from scotti.models.contract import MAX_COUNT, META_WINDOW, WINDOW_INPUT_FRAMES
from scotti.models.kv_streaming import KvStepRuntime, open_step_model
from scotti.models.runtime import ScottiRuntime, window_graph_for


def _window_of(path: Path) -> int:
    meta = {p.key: p.value for p in onnx.load(str(path), load_external_data=False).metadata_props}
    return int(meta[META_WINDOW])


def _dims(vi: onnx.ValueInfoProto) -> list[int] | None:
    shape = vi.type.tensor_type.shape
    out = []
    for d in shape.dim:
        if not d.HasField("dim_value"):
            return None
        out.append(int(d.dim_value))
    return out


def graph_flops(path: Path) -> int:
    """2 x multiply-adds of Conv, ConvInteger, MatMul(Integer), Gemm at batch 1."""
    model = onnx.load(str(path))
    for vi in model.graph.input:  # fix every symbolic dim (the batch) to 1
        for d in vi.type.tensor_type.shape.dim:
            if not d.HasField("dim_value"):
                d.dim_value = 1
    model = shape_inference.infer_shapes(model, data_prop=True)
    shapes: dict[str, list[int] | None] = {}
    for vi in [*model.graph.value_info, *model.graph.input, *model.graph.output]:
        shapes[vi.name] = _dims(vi)
    for init in model.graph.initializer:
        shapes[init.name] = list(init.dims)
    total = 0
    for node in model.graph.node:
        op = node.op_type
        if op in ("Conv", "ConvInteger"):
            w, y = shapes.get(node.input[1]), shapes.get(node.output[0])
            if w and y:
                total += 2 * math.prod(y) * math.prod(w[1:])
        elif op in ("MatMul", "MatMulInteger", "Gemm"):
            a, y = shapes.get(node.input[0]), shapes.get(node.output[0])
            if a and y:
                transposed = op == "Gemm" and any(
                    at.name == "transA" and at.i == 1 for at in node.attribute
                )
                k = a[-2] if transposed else a[-1]
                total += 2 * math.prod(y) * k
    return total


def timed(call: Any, n: int) -> np.ndarray:
    out = np.empty(n)
    for i in range(n):
        start = time.perf_counter_ns()
        call()
        out[i] = (time.perf_counter_ns() - start) / 1e6
    return out


def latency(models: list[Path], threads: int, steps: int) -> dict[str, dict[str, float]]:
    """Per model: step median/p99 (ms) and window-recompute median/p99, interleaved."""
    rng = np.random.default_rng(0)
    calls: dict[str, Any] = {}
    for path in models:
        with_window(_window_of(path))  # see any_window.py: T=20 models are outside the contract
        step = open_step_model(path, threads=threads)
        window = ScottiRuntime(window_graph_for(path), threads=threads)
        if isinstance(step, KvStepRuntime):  # batch 1 on warm caches, as the daemon steps it
            one, *rest = step_inputs(step, [1])[1]
            calls[f"{path}|step"] = lambda s=step, f=one, r=tuple(rest): step_rows(s, f, r)
        else:
            frame = rng.uniform(0, MAX_COUNT, step.frame_shape).astype(np.float32)
            past = rng.normal(size=(step.window - 1, step.embed_dim)).astype(np.float32)
            calls[f"{path}|step"] = lambda s=step, f=frame, p=past: s.step(f, p)
        frames = rng.uniform(0, MAX_COUNT, (1, step.window, *step.frame_shape)).astype(np.float32)
        session = window._session  # the raw call, no batching loop around it
        calls[f"{path}|window"] = lambda s=session, x=frames: s.run(None, {WINDOW_INPUT_FRAMES: x})
    for call in calls.values():  # warm-up
        for _ in range(20):
            call()
    times: dict[str, list[float]] = {k: [] for k in calls}
    for _ in range(steps):
        for key, call in calls.items():
            times[key].extend(timed(call, 1))
    out: dict[str, dict[str, float]] = {}
    for key, ms in times.items():
        name, graph = key.split("|")
        entry = out.setdefault(name, {})
        entry[f"{graph}_median_ms"] = float(np.median(ms))
        entry[f"{graph}_p99_ms"] = float(np.percentile(ms, 99))
    return out


def describe(models: list[Path], threads: list[int], steps: int) -> dict[str, dict[str, Any]]:
    result: dict[str, dict[str, Any]] = {}
    for path in models:
        window = window_graph_for(path)
        result[str(path)] = {
            "bytes": path.stat().st_size + window.stat().st_size,
            "step_bytes": path.stat().st_size,
            "step_flops": graph_flops(path),
            "window_flops": graph_flops(window),
            "latency": {},
        }
    for k in threads:
        for name, entry in latency(models, k, steps).items():
            result[name]["latency"][str(k)] = entry
    return result


def conv_int8(src: Path, dst: Path) -> Path:
    """int8 dynamic quantization with Conv included (scotti export leaves Conv fp32)."""
    if dst.is_file() and dst.stat().st_mtime > src.stat().st_mtime:
        return dst
    from scotti.export.quantize import quantize_int8

    quantize_int8(src, dst, ops=("Conv", "MatMul", "Gemm"))
    return dst


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python experiments/measure.py", description=__doc__)
    parser.add_argument("models", nargs="+", type=Path)
    parser.add_argument("--steps", type=int, default=400)
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    args = parser.parse_args(argv)
    print(json.dumps(describe(args.models, args.threads, args.steps), indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
