"""Per-frame latency: streaming step vs recomputing the whole window, fp32 vs int8.

``python -m scotti.export.bench_step --embed-dim 512 --layers 4``

Builds a model of the given size (random weights: latency does not depend on
training), exports and proves it with int8 copies, then times one onnxruntime
call per frame, batch 1, on 1 and 2 intra-op threads (spinning off). Prints
medians, p99 and the ratios measured in this same run. A benchmark, not a test.

``python -m scotti.export.bench_step --model models/scotti-default.onnx
[--int8 NAME.int8.onnx] [--batches 1 8 32] [--threads 1]``

An exported model instead, beside its int8 copy (made for the run by
``export.quantize`` unless ``--int8`` names one): the step graph as the daemon and
``scotti eval`` call it (``ScottiRuntime.run_steps``, B frames a call), ms per
frame at each batch size, the graphs and sizes taking turns call by call.
Inputs are insole frames of a recorded session when ``--session`` names one
(else random counts) with the embeddings the model gives them.
"""

from __future__ import annotations

import argparse
import functools
import os
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import numpy.typing as npt
import torch
from scotti.export.errors import ExportError
from scotti.export.model import Scotti, ScottiConfig
from scotti.export.onnx_export import Checkpoint, GraphPaths, export_model
from scotti.export.parity import format_report, run, session
from scotti.export.quantize import int8_copies
from scotti.models import contract
from scotti.models.errors import ModelError
from scotti.models.runtime import ScottiRuntime


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


def step_inputs(
    runtime: ScottiRuntime, batch: int, session: Path | None, seed: int = 0
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
    """``batch`` frames and each one's T-1 embeddings before it: consecutive frames of
    ``session`` (its first 4,000 paired frames, rows spread over them) and the
    embeddings the model gives them, else random counts and embeddings."""
    rng = np.random.default_rng(seed)
    t, e = runtime.window, runtime.embed_dim
    if session is None:
        drawn = rng.integers(0, contract.MAX_COUNT // 3, (batch, *runtime.frame_shape))
        embedded = rng.normal(size=(batch, t - 1, e))
        return drawn.astype(np.float32), embedded.astype(np.float32)
    from scotti.firmware_protocol.frame_path import stream_pairs
    from scotti.firmware_protocol.session import PacketRecord, SessionReader

    held = []
    with SessionReader(session) as reader:
        chunks = ((r.t_ns, r.data) for r in reader if isinstance(r, PacketRecord))
        for pair in stream_pairs(chunks):  # read only as far as the frames it keeps
            held.append(pair.counts)
            if len(held) == 4000:
                break
    if len(held) < t + batch:
        msg = f"{session}: {len(held)} paired frames, fewer than T + {batch}"
        raise ValueError(msg)
    counts = np.stack(held).astype(np.float32)
    none = np.zeros((len(counts), t - 1, e), np.float32)
    # A frame's embedding depends on that frame alone: any past gives it.
    parts = [
        runtime.run_steps(counts[i : i + 256], none[i : i + 256]).embedding
        for i in range(0, len(counts), 256)
    ]
    emb = np.concatenate(parts)
    at = np.linspace(t - 1, len(counts) - 1, batch).astype(np.int64)
    past = np.stack([emb[j - t + 1 : j] for j in at]).astype(np.float32)
    return counts[at], past


def batch_dependence(
    runtime: ScottiRuntime, frames: npt.NDArray[np.float32], past: npt.NDArray[np.float32]
) -> dict[str, float]:
    """How far a frame's prediction moves with the frames beside it in its call: one call
    of B frames against B calls of one (max abs difference; 0 for a graph whose rows do
    not see each other). Dynamic int8 quantizes a call's activations with one scale."""
    together = runtime.run_steps(frames, past)
    alone = [runtime.run_steps(frames[i : i + 1], past[i : i + 1]) for i in range(len(frames))]
    pose = np.concatenate([a.pose for a in alone])
    progress = np.concatenate([a.progress for a in alone])
    probs = np.concatenate([a.action_probs for a in alone])
    return {
        "pose_mm": float(np.abs(pose - together.pose).max() * 1e3),
        "progress": float(np.abs(progress - together.progress).max()),
        "action_probs": float(np.abs(probs - together.action_probs).max()),
        "actions_changed": int((probs.argmax(1) != together.action_probs.argmax(1)).sum()),
    }


def bench_model(
    graphs: dict[str, Path],
    batches: Sequence[int],
    threads: Sequence[int],
    rounds: int,
    session: Path | None,
) -> list[str]:
    """ms per frame of ``run_steps`` for each graph, batch size and thread count; the
    graphs and batch sizes take turns call by call."""
    calls: dict[tuple[str, int, int], Callable[[], object]] = {}
    notes = []
    for k in threads:
        for name, path in graphs.items():
            runtime = ScottiRuntime(path, threads=k)
            for b in batches:
                frames, past = step_inputs(runtime, b, session)
                calls[name, b, k] = functools.partial(runtime.run_steps, frames, past)
            if k == threads[0]:
                d = batch_dependence(runtime, frames, past)
                notes.append(
                    f"{name}: one call of {len(frames)} frames against {len(frames)} calls of "
                    f"one: pose moves up to {d['pose_mm']:.2f} mm, progress "
                    f"{d['progress']:.4f}, action probabilities {d['action_probs']:.4f}, "
                    f"{d['actions_changed']} actions changed"
                )
    for _ in range(max(3, rounds // 10)):  # onnxruntime plans each new shape once
        for call in calls.values():
            call()
    wall = {key: np.empty(rounds) for key in calls}
    cpu = {key: np.empty(rounds) for key in calls}
    for i in range(rounds):
        for key, call in calls.items():
            start, start_cpu = time.perf_counter_ns(), time.process_time_ns()
            call()
            wall[key][i] = (time.perf_counter_ns() - start) / 1e6 / key[1]
            cpu[key][i] = (time.process_time_ns() - start_cpu) / 1e6 / key[1]
    lines = [
        "| graph | threads | frames per call | ms per frame, min | median | p99 "
        "| CPU ms per frame, median | vs the first graph (min; CPU median) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    first = next(iter(graphs))
    for key in calls:
        name, b, k = key
        ms, used = wall[key], float(np.median(cpu[key]))
        # On a shared host the minimum is the call that nothing else slowed down.
        vs_min = ms.min() / wall[first, b, k].min()
        vs_cpu = used / float(np.median(cpu[first, b, k]))
        lines.append(
            f"| {name} | {k} | {b} | {ms.min():.3f} | {float(np.median(ms)):.3f} "
            f"| {float(np.percentile(ms, 99)):.3f} | {used:.3f} | {vs_min:.2f}x; {vs_cpu:.2f}x |"
        )
    return [*lines, "", *notes]


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m scotti.export.bench_step")
    parser.add_argument(
        "--model", type=Path, default=None, help="an exported step graph, beside its int8 copy"
    )
    parser.add_argument(
        "--int8", type=Path, default=None, help="with --model: its int8 copy (default: made)"
    )
    parser.add_argument(
        "--batches", type=int, nargs="+", default=[1, 8, 32], help="with --model: frames a call"
    )
    parser.add_argument(
        "--session", type=Path, default=None, help="with --model: frames from this session"
    )
    parser.add_argument("--embed-dim", type=int, default=512)
    parser.add_argument("--layers", type=int, default=4)
    parser.add_argument("--heads", type=int, default=8)
    parser.add_argument("--window", type=int, default=contract.WINDOW)
    parser.add_argument("--frames", type=int, default=200, help="timed calls per graph")
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    args = parser.parse_args(argv)
    if args.model is not None:
        return main_model(args)
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


def main_model(args: argparse.Namespace) -> int:
    """``--model``: the exported graph beside its int8 copy."""
    if min(args.batches) < 1 or min(args.threads) < 1 or args.frames < 1:
        print("bench_step: --batches, --threads and --frames must be at least 1", file=sys.stderr)
        return 2
    try:
        with tempfile.TemporaryDirectory() as tmp:
            int8 = args.int8 or int8_copies(args.model, Path(tmp))[0]
            graphs = {"fp32": args.model, "int8": int8}
            for name, path in graphs.items():
                print(f"{name}: {path} ({path.stat().st_size / 1e6:.2f} MB)")
            load = os.getloadavg()[0]
            lines = bench_model(graphs, args.batches, args.threads, args.frames, args.session)
    except (ExportError, ModelError, ValueError, OSError) as exc:
        print(f"bench_step: {exc}", file=sys.stderr)
        return 2
    print(
        f"{args.frames} timed calls of each after a warm-up, load average "
        f"{load:.1f} -> {os.getloadavg()[0]:.1f}; inputs: "
        f"{args.session or 'random counts and embeddings'}"
    )
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
