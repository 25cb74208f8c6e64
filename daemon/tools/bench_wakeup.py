"""What a frame costs after the host has been idle: the model's step, batch 1, run after
gaps of idle time, beside a plain numpy product as the host's own reference.

    python -m scotti.daemon.tools.bench_wakeup [--model M] [--gaps-ms 0 2 10 30 62.5]
        [--calls 60]

One pair at 16 Hz gives the daemon a frame every 62.5 ms and nothing between: the
cores idle, and on some hosts (virtual machines, power-saving governors, deep sleep
states) the work that follows runs several times slower than the same work done
back to back. The many-pairs bench (``bench --pairs 1``) then shows a daemon costing
far more per pair than the model's step measured hot (``--step-batches``). This
measures it without the daemon: the step's CPU time (this thread's clock) and wall
time per call, each call after a few calls back to back and ``gap`` ms of sleep,
the gaps in turns; the numpy
product says whether it is the host (both slow down) or the model (only it does).
A measurement, not a test: run it on the host the daemon will run on.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

DEFAULT_MODEL = Path(__file__).resolve().parents[2] / "models" / "scotti-default.onnx"


WARM_CALLS = 3  # back-to-back calls before the gap: the host busy, as after a frame


def timed_after_gap(work: Callable[[], object], gap_s: float) -> tuple[float, float]:
    """(this thread's CPU ms, wall ms) of one call of ``work`` after a few calls back to
    back and then ``gap_s`` of sleep (0: the next call back to back)."""
    for _ in range(WARM_CALLS):
        work()
    if gap_s > 0:
        time.sleep(gap_s)
    cpu, wall = time.thread_time(), time.perf_counter()
    work()
    return (time.thread_time() - cpu) * 1e3, (time.perf_counter() - wall) * 1e3


def measure(
    works: dict[str, Callable[[], object]], gaps_ms: list[float], calls: int
) -> dict[tuple[str, float], tuple[float, float]]:
    """Median (CPU ms, wall ms) of each work after each gap, gaps and works in turns."""
    samples: dict[tuple[str, float], list[tuple[float, float]]] = {
        (name, gap): [] for name in works for gap in gaps_ms
    }
    for _ in range(calls):
        for gap in gaps_ms:
            for name, work in works.items():
                samples[name, gap].append(timed_after_gap(work, gap / 1e3))
    return {
        key: (float(np.median([s[0] for s in v])), float(np.median([s[1] for s in v])))
        for key, v in samples.items()
    }


def step_work(model: Path) -> Callable[[], object]:
    """One call of the model's step on one frame with a warm cache, as the daemon's."""
    from scotti.daemon.tools.step_costs import run_step, step_inputs
    from scotti.models.kv_streaming import open_step_model

    runtime = open_step_model(model)
    frames, *rest = step_inputs(runtime, [1])[1]
    arrays = tuple(rest)
    for _ in range(20):  # onnxruntime plans the shape, the caches fill
        run_step(runtime, frames, arrays)
    return lambda: run_step(runtime, frames, arrays)


def numpy_work() -> Callable[[], object]:
    a = np.random.default_rng(0).random((256, 256))
    return lambda: a @ a


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m scotti.daemon.tools.bench_wakeup",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--model", type=Path, default=DEFAULT_MODEL)
    p.add_argument("--gaps-ms", type=float, nargs="+", default=[0.0, 2.0, 10.0, 30.0, 62.5])
    p.add_argument("--calls", type=int, default=60, help="calls per gap and work")
    args = p.parse_args(argv)
    if args.calls < 1 or any(g < 0 for g in args.gaps_ms):
        print("bench_wakeup: --calls must be >= 1 and every gap >= 0", file=sys.stderr)
        return 2
    try:
        works = {
            "model step, 1 frame": step_work(args.model),
            "numpy 256x256 product": numpy_work(),
        }
    except (OSError, ValueError) as exc:
        print(f"bench_wakeup: {exc}", file=sys.stderr)
        return 2
    result = measure(works, args.gaps_ms, args.calls)
    print(
        f"after idle gaps, {args.calls} calls each, medians ({args.model.name}; "
        f"load average {os.getloadavg()[0]:.1f})"
    )
    print("| work | gap ms | CPU ms | wall ms | CPU vs no gap |")
    print("|---|---|---|---|---|")
    for name in works:
        base = result[name, min(args.gaps_ms)][0]
        for gap in args.gaps_ms:
            cpu, wall = result[name, gap]
            ratio = f"{cpu / base:.1f}x" if base > 0 else "-"
            print(f"| {name} | {gap:g} | {cpu:.3f} | {wall:.3f} | {ratio} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
