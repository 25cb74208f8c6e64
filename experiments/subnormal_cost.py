"""What subnormal weights cost an exported model per call, and what removes the cost.

    python experiments/subnormal_cost.py [models/scotti-default.onnx] [--rounds 3] [--calls 300]

Counts the graph's float32 weights below 1.2e-38 (subnormal: x86 multiplies
them through a microcode assist), writes a copy of both graphs with those
weights set to 0 (what ``scotti export`` now writes, export/subnormals.py),
and times a call of the step graph and of the window graph (batch 1, one
thread, median) four ways:

- ``ieee``: the graph as it is, onnxruntime keeping subnormals (its default);
- ``daz``: the graph as it is, with onnxruntime's ``session.set_denormal_as_zero``
  (not what the daemon does: models/subnormal_weights.py says why);
- ``zeroed``: the zeroed copy, onnxruntime's default;
- ``daemon``: the graph as it is, opened as the daemon opens it
  (``models.graph_checks.open_session``: its subnormal weights zeroed in memory).

onnxruntime applies the denormal setting once per process, so each way runs
in its own process; the ways take turns round by round, so load from other
processes hits them alike. The zeroed and the daemon's outputs are compared with the
original's on the same inputs (max abs difference).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scotti.models.subnormal_weights import without_subnormal_weights

ROOT = Path(__file__).resolve().parent.parent
WAYS = ("ieee", "daz", "zeroed", "daemon")


def window_graph(step: Path) -> Path:
    return step.with_name(step.name.removesuffix(".onnx") + ".window.onnx")


def zero_subnormals(src: Path, dst: Path) -> int:
    """Copy ``src`` to ``dst`` with subnormal float32 weights set to 0 (the daemon's own
    zeroing, models/subnormal_weights.py); how many there were."""
    zeroed = without_subnormal_weights(src)
    dst.write_bytes(zeroed[0] if zeroed is not None else src.read_bytes())
    return zeroed[1] if zeroed is not None else 0


def _inputs(session: object, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    feed = {}
    for arg in session.get_inputs():  # type: ignore[attr-defined]
        shape = [1 if not isinstance(d, int) else d for d in arg.shape]
        scale = 2000.0 if arg.name in ("frame", "frames") else 1.0  # raw counts vs embeddings
        feed[arg.name] = (rng.random(shape) * scale).astype(np.float32)
    return feed


def child(graph: Path, way: str, calls: int) -> None:
    """One way in this process: median ms per call, and the outputs of the first call."""
    import onnxruntime as ort
    from scotti.models.graph_checks import open_session

    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    options.inter_op_num_threads = 1
    if way == "daz":
        options.add_session_config_entry("session.set_denormal_as_zero", "1")
    result = {}
    for kind, path in (("step", graph), ("window", window_graph(graph))):
        if way == "daemon":
            session = open_session(path, threads=1)
        else:
            session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        feed = _inputs(session)
        first = session.run(None, feed)
        for _ in range(20):
            session.run(None, feed)
        times = []
        for _ in range(calls):
            start = time.perf_counter()
            session.run(None, feed)
            times.append(time.perf_counter() - start)
        outputs = [o.tolist() for o in first]
        result[kind] = {"ms": 1000 * float(np.median(times)), "outputs": outputs}
    print(json.dumps(result))


def run_way(graph: Path, way: str, calls: int) -> dict[str, dict[str, object]]:
    cmd = [sys.executable, __file__, str(graph), "--child", way]
    out = subprocess.run([*cmd, "--calls", str(calls)], capture_output=True, text=True, check=True)
    return dict(json.loads(out.stdout))


def max_diff(a: list[object], b: list[object]) -> float:
    pairs = zip(a, b, strict=True)
    return max(float(np.max(np.abs(np.asarray(x) - np.asarray(y)))) for x, y in pairs)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("model", nargs="?", type=Path, default=ROOT / "models/scotti-default.onnx")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--calls", type=int, default=300)
    parser.add_argument("--child", choices=("ieee", "daz", "daemon"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        child(args.model, args.child, args.calls)
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        zeroed_graph = Path(tmp) / args.model.name
        counts = [
            zero_subnormals(args.model, zeroed_graph),
            zero_subnormals(window_graph(args.model), window_graph(zeroed_graph)),
        ]
        ms: dict[str, dict[str, list[float]]] = {w: {"step": [], "window": []} for w in WAYS}
        diffs: dict[str, float] = {}
        for _ in range(args.rounds):
            got = {
                "ieee": run_way(args.model, "ieee", args.calls),
                "daz": run_way(args.model, "daz", args.calls),
                "zeroed": run_way(zeroed_graph, "ieee", args.calls),
                "daemon": run_way(args.model, "daemon", args.calls),
            }
            for way in WAYS:
                for kind in ("step", "window"):
                    ms[way][kind].append(float(got[way][kind]["ms"]))  # type: ignore[arg-type]
            for kind in ("step", "window"):
                a = got["ieee"][kind]["outputs"]
                for way in ("zeroed", "daemon"):
                    b = got[way][kind]["outputs"]
                    diffs[kind] = max(diffs.get(kind, 0.0), max_diff(a, b))  # type: ignore[arg-type]
    print(f"{args.model}: subnormal weights: step graph {counts[0]:,}, window graph {counts[1]:,}")
    print(f"median ms per call, batch 1, 1 thread, median of {args.rounds} rounds x {args.calls}:")
    print("| graph | ieee (as is) | daz (session option) | zeroed file | daemon | ieee / daemon |")
    print("|---|---|---|---|---|---|")
    for kind in ("step", "window"):
        med = {w: float(np.median(ms[w][kind])) for w in WAYS}
        print(
            f"| {kind} | {med['ieee']:.2f} | {med['daz']:.2f} | {med['zeroed']:.2f} "
            f"| {med['daemon']:.2f} | {med['ieee'] / med['daemon']:.1f}x |"
        )
    print(
        "outputs, zeroed and daemon against as is, max abs difference: "
        f"step {diffs['step']:.1e}, window {diffs['window']:.1e}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
