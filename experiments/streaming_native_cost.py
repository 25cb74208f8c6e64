"""CPU per streaming step: the paper form's step graph vs the streaming-native one.

``python experiments/streaming_native_cost.py [--batches 1 8 32] [--repeats 7] [--calls 200]``

Builds both forms at the shipped size (T=40, E=128, 2 layers, 4 heads, conv
[16, 32], head hidden 128; untrained weights: the cost does not depend on them),
exports and proves both (export/onnx_export.py), then times the step graph in
onnxruntime with 1 intra-op thread at each batch size. The two graphs take turns
within every repeat (load from other processes hits both alike); each repeat is
``--calls`` calls. Beside the graphs alone, each form's runtime ``push_many`` (the
whole per-frame path a daemon would call: caches, input checks, results). The table
gives per-frame milliseconds (call time / batch), min and median over repeats, of
wall time and of this process's CPU time (``time.process_time``: what the step
costs a core, less sensitive to load).
A benchmark, not a test. docs/streaming-native.md has a run's output.
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
from scotti.export.model import Scotti, ScottiConfig
from scotti.export.model_streaming import kv_slots
from scotti.export.onnx_export import Checkpoint, export_model
from scotti.export.parity import session
from scotti.models import contract
from scotti.models.kv_contract import KV_INPUT_PAST, KV_INPUT_VALID
from scotti.models.kv_streaming import KvStepRuntime, KvStreamingWindow
from scotti.models.kv_streaming import push_many as kv_push_many
from scotti.models.runtime import ScottiRuntime
from scotti.models.streaming import StreamingWindow
from scotti.models.streaming import push_many as paper_push_many

SHIPPED = {"embed_dim": 128, "layers": 2, "heads": 4, "conv_channels": (16, 32), "head_hidden": 128}


def feeds_for(cfg: ScottiConfig, batch: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """A steady-state step's inputs (a full cache) for ``batch`` insole pairs."""
    frame = rng.uniform(0, contract.MAX_COUNT, (batch, *cfg.frame_shape)).astype(np.float32)
    if cfg.arch == "paper":
        past = rng.normal(size=(batch, cfg.window - 1, cfg.embed_dim)).astype(np.float32)
        return {contract.STEP_INPUT_FRAME: frame, contract.STEP_INPUT_PAST: past}
    shape = (batch, cfg.window - 1, kv_slots(cfg.layers), cfg.embed_dim)
    return {
        contract.STEP_INPUT_FRAME: frame,
        KV_INPUT_PAST: rng.normal(size=shape).astype(np.float32),
        KV_INPUT_VALID: np.ones((batch, cfg.window - 1), np.float32),
    }


def measure(
    calls: dict[str, Callable[[], object]], repeats: int, n: int
) -> dict[str, tuple[list[float], list[float]]]:
    """Per repeat, wall and CPU ms per call of each callable; they take turns."""
    for call in calls.values():  # warm-up: allocations, first-run kernels
        for _ in range(10):
            call()
    out: dict[str, tuple[list[float], list[float]]] = {k: ([], []) for k in calls}
    for _ in range(repeats):
        for name, call in calls.items():
            wall, cpu = time.perf_counter(), time.process_time()
            for _ in range(n):
                call()
            out[name][0].append((time.perf_counter() - wall) * 1e3 / n)
            out[name][1].append((time.process_time() - cpu) * 1e3 / n)
    return out


def runtime_calls(
    steps: dict[str, Path], batch: int, rng: np.random.Generator
) -> dict[str, Callable[[], object]]:
    """The whole per-frame path of each form's runtime: ``push_many`` of ``batch``
    windows (cache copies in and out, input checks, results), full windows."""
    paper = ScottiRuntime(steps["paper"], threads=1)
    kv = KvStepRuntime(steps["streaming"], threads=1)
    shape = (batch, *paper.frame_shape)
    frames = list(rng.uniform(0, contract.MAX_COUNT, shape).astype(np.float32))
    paper_windows = [StreamingWindow(paper) for _ in range(batch)]
    kv_windows = [KvStreamingWindow(kv) for _ in range(batch)]
    for _ in range(paper.window):  # past warming: every call below predicts
        paper_push_many(paper_windows, frames)
        kv_push_many(kv_windows, frames)
    return {
        "paper push_many": functools.partial(paper_push_many, paper_windows, frames),
        "streaming push_many": functools.partial(kv_push_many, kv_windows, frames),
    }


def export_form(arch: str, directory: Path) -> Path:
    torch.manual_seed(0)
    model = Scotti(ScottiConfig(**SHIPPED, arch=arch)).eval()  # type: ignore[arg-type]
    ckpt = Checkpoint(model=model, training_data="none: untrained, for timing")
    result = export_model(ckpt, directory / f"{arch}.onnx")
    worst = max(d for diffs in result.parity.values() for d in diffs.values())
    print(f"{arch}: {model.num_parameters():,} parameters, parity max abs diff {worst:.2e}")
    return result.paths.step


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="streaming_native_cost")
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 8, 32])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--calls", type=int, default=200, help="calls per repeat at batch 1")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as tmp:
        steps = {arch: export_form(arch, Path(tmp)) for arch in ("paper", "streaming")}
        cfgs = {a: ScottiConfig(**SHIPPED, arch=a) for a in steps}  # type: ignore[arg-type]
        sessions = {a: session(p, threads=1) for a, p in steps.items()}
        rng = np.random.default_rng(0)
        print(
            f"{'batch':>5s} {'form':19s} {'wall ms/frame min':>18s} {'median':>8s} "
            f"{'cpu ms/frame min':>17s} {'median':>8s}"
        )
        ratios = []
        for batch in args.batches:
            feeds = {a: feeds_for(cfgs[a], batch, rng) for a in steps}
            calls: dict[str, Callable[[], object]] = {
                a: functools.partial(sessions[a].run, None, feeds[a]) for a in steps
            }
            calls.update(runtime_calls(steps, batch, rng))
            n = max(args.calls // batch, 10)
            res = measure(calls, args.repeats, n)
            for arch, (wall, cpu) in res.items():  # graph alone, then runtime.push_many
                w, c = np.array(wall) / batch, np.array(cpu) / batch
                print(
                    f"{batch:5d} {arch:19s} {w.min():18.4f} {np.median(w):8.4f} "
                    f"{c.min():17.4f} {np.median(c):8.4f}"
                )
            for what in ("", " push_many"):
                paper, kv = (np.median(res[a + what][1]) for a in ("paper", "streaming"))
                ratios.append(f"batch {batch}{what}: streaming/paper CPU (median) {kv / paper:.2f}")
        print("\n".join(ratios))
    return 0


if __name__ == "__main__":
    sys.exit(main())
