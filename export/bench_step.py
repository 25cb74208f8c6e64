"""Per-frame latency: streaming step vs recomputing the whole window, fp32 vs int8.

``python -m scotti.export.bench_step --embed-dim 512 --layers 4``

Builds a model of the given size (random weights: latency does not depend on
training), exports and proves it with int8 copies, then times one onnxruntime
call per frame, batch 1, on 1 and 2 intra-op threads (spinning off). Prints
medians, p99 and the ratios measured in this same run. A benchmark, not a test.
"""

from __future__ import annotations

import argparse
import functools
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import torch
from scotti.export.errors import ExportError
from scotti.export.model import Scotti, ScottiConfig
from scotti.export.onnx_export import Checkpoint, GraphPaths, export_model
from scotti.export.parity import format_report, run, session
from scotti.models import contract


def time_interleaved(
    calls: dict[str, Callable[[], object]], n: int, warmup: int
) -> dict[str, np.ndarray]:
    """Milliseconds per call, the graphs taking turns so that load from other
    processes on a shared machine hits them all alike."""
    for _ in range(warmup):
        for call in calls.values():
            call()
    times = {name: np.empty(n) for name in calls}
    for i in range(n):
        for name, call in calls.items():
            start = time.perf_counter_ns()
            call()
            times[name][i] = (time.perf_counter_ns() - start) / 1e6
    return times


def bench(paths: GraphPaths, cfg: ScottiConfig, threads: Sequence[int], n: int) -> list[str]:
    rng = np.random.default_rng(0)
    frame = rng.uniform(0, contract.MAX_COUNT, (1, *cfg.frame_shape)).astype(np.float32)
    past = rng.normal(size=(1, cfg.window - 1, cfg.embed_dim)).astype(np.float32)
    frames = rng.uniform(0, contract.MAX_COUNT, (1, cfg.window, *cfg.frame_shape))
    step_feeds = {contract.STEP_INPUT_FRAME: frame, contract.STEP_INPUT_PAST: past}
    window_feeds = {contract.WINDOW_INPUT_FRAMES: frames.astype(np.float32)}
    graphs = {
        ("fp32", "step"): paths.step,
        ("fp32", "window"): paths.window,
        ("int8", "step"): paths.int8_step,
        ("int8", "window"): paths.int8_window,
    }
    lines = [f"{'graph':14s} {'threads':>7s} {'median ms':>10s} {'p99 ms':>8s}"]
    medians: dict[tuple[str, str, int], float] = {}
    for k in threads:
        calls: dict[str, Callable[[], object]] = {}
        for (precision, graph), path in graphs.items():
            sess = session(path, threads=k)
            feeds = step_feeds if graph == "step" else window_feeds
            calls[f"{precision} {graph}"] = functools.partial(run, sess, feeds)
        times = time_interleaved(calls, n, warmup=max(5, n // 10))
        for precision, graph in graphs:
            ms = times[f"{precision} {graph}"]
            medians[precision, graph, k] = float(np.median(ms))
            p99 = float(np.percentile(ms, 99))
            label = f"{precision} {graph}"
            lines.append(f"{label:14s} {k:7d} {medians[precision, graph, k]:10.3f} {p99:8.3f}")
    lines.append("ratios (medians, this run):")
    for k in threads:
        for precision in ("fp32", "int8"):
            ratio = medians[precision, "window", k] / medians[precision, "step", k]
            lines.append(
                f"  {precision} window / step (streaming gain), {k} thread(s): {ratio:.2f}x"
            )
        for graph in ("step", "window"):
            ratio = medians["fp32", graph, k] / medians["int8", graph, k]
            lines.append(f"  {graph} fp32 / int8 (int8 gain), {k} thread(s): {ratio:.2f}x")
    if len(threads) > 1:
        first, last = threads[0], threads[-1]
        for precision, graph in graphs:
            speedup = medians[precision, graph, first] / medians[precision, graph, last]
            lines.append(
                f"  {precision} {graph} speed-up {first} -> {last} threads: {speedup:.2f}x"
            )
    return lines


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m scotti.export.bench_step")
    parser.add_argument("--embed-dim", type=int, default=512)
    parser.add_argument("--layers", type=int, default=4)
    parser.add_argument("--heads", type=int, default=8)
    parser.add_argument("--window", type=int, default=contract.WINDOW)
    parser.add_argument("--frames", type=int, default=200, help="timed calls per graph")
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    args = parser.parse_args(argv)
    try:
        cfg = ScottiConfig(
            window=args.window, embed_dim=args.embed_dim, layers=args.layers, heads=args.heads
        )
        torch.manual_seed(0)
        model = Scotti(cfg).eval()
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            result = export_model(Checkpoint(model=model), Path(tmp) / "bench.onnx", int8=True)
            print(
                f"exported and proved in {time.perf_counter() - t0:.1f} s: "
                f"{model.num_parameters():,} parameters, T={cfg.window}, E={cfg.embed_dim}, "
                f"layers={cfg.layers}, heads={cfg.heads}"
            )
            for kind, entry in result.card["files"].items():
                print(f"  {kind:12s} {entry['bytes'] / 1e6:7.2f} MB")
            for line in format_report(result.parity) + format_report(result.int8_drift):
                print(f"  {line}")
            for line in bench(result.paths, cfg, args.threads, args.frames):
                print(line)
    except (ExportError, ValueError) as exc:
        print(f"bench_step: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
