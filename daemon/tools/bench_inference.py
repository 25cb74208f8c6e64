"""The inference thread's CPU per frame, outside the daemon: the model's own, and the rest.

    python -m scotti.daemon.tools.bench_inference --devices 1 8 32 64
    python -m scotti.daemon.tools.bench_inference --baseline /tmp/wt-inf   # A/B, interleaved

For N devices, N windows on one shared model are fed as the daemon's engine feeds
them: every turn, one frame of each device, in calls of at most ``--max-batch``
frames (the engine's ``_take_ready`` and ``_run_batch``, results handed to an event
loop as in the daemon). Two kinds of frames:

- ``sim``: insole frames from a simulated session (``scotti sim``'s renderer, every
  action, sensor effects); they pass the input checks, as a lab session's do;
- ``random``: uniform random counts, as ``bench`` sends; they break the outline rule,
  so every prediction is flagged out_of_range and the window verdict runs each time.

CPU is ``time.process_time`` around each turn (the inference thread's work) and around
each ``InferenceSession.run`` alone; "python" is the difference. Per repeat the figures
are per frame; the table gives min and median over repeats. ``--baseline DIR`` runs
the same measurement on the code of another checkout (``git worktree add DIR REV``) in
child processes interleaved with this one's, so that a busy host weighs on both alike.
A measurement, never a test.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from scotti.daemon.inference.engine import InferenceEngine, InferenceJob, InferenceResult
from scotti.daemon.inference.window import Window
from scotti.firmware_protocol.pairing import PairedFrame
from scotti.models.contract import FRAME_COLS, FRAME_ROWS, MAX_COUNT
from scotti.models.kv_streaming import StepModel, open_step_model

DEFAULT_MODEL = Path(__file__).resolve().parents[2] / "models" / "scotti-default.onnx"


class _TimedSession:
    """An onnxruntime session that adds up the CPU its ``run`` takes."""

    def __init__(self, session: Any) -> None:
        self._session = session
        self.cpu_s = 0.0
        self.calls = 0

    def run(self, *args: Any, **kwargs: Any) -> Any:
        start = time.process_time()
        try:
            return self._session.run(*args, **kwargs)
        finally:
            self.cpu_s += time.process_time() - start
            self.calls += 1

    def __getattr__(self, name: str) -> Any:
        return getattr(self._session, name)


def sim_frames(seconds: float = 40.0) -> npt.NDArray[np.uint16]:
    """(N, H, 2W) paired frames of a simulated session: every action, realistic effects."""
    from scotti.sim.bench import bench_scene
    from scotti.sim.effects.registry import EffectPlan, parse_effects
    from scotti.sim.foot import draw_feet
    from scotti.sim.insole import InsoleArray
    from scotti.sim.pressure import PressureRenderer
    from scotti.sim.scene import PHYSICS_OVERSAMPLE, build_motion
    from scotti.sim.writer import CountsStream, sim_input

    scene = bench_scene(seconds / 60.0, effects=True)
    sim = sim_input(build_motion(scene, PHYSICS_OVERSAMPLE))
    feet = draw_feet(sim.foot_length_m, scene.subject.style_seed, scene.seed)
    renderer = PressureRenderer(sim.foot_length_m, feet)
    plan = EffectPlan.build(
        parse_effects(scene.effects), seed=scene.seed, rate_hz=sim.rate_hz, mask=renderer.mask
    )
    insole = InsoleArray(scene.insole.resolved(), scene.seed)
    feet_counts = CountsStream(sim.loads(), renderer, plan, insole).all()  # (N, foot, H, W)
    n = len(feet_counts)
    return np.ascontiguousarray(
        feet_counts.transpose(0, 2, 1, 3).reshape(n, FRAME_ROWS, 2 * FRAME_COLS)
    )


def random_frames(count: int = 640, seed: int = 0) -> npt.NDArray[np.uint16]:
    """(N, H, 2W) uniform random counts, as ``bench``'s boards send."""
    rng = np.random.default_rng(seed)
    shape = (count, FRAME_ROWS, 2 * FRAME_COLS)
    return rng.integers(0, MAX_COUNT // 3, shape, dtype=np.uint16)


def measure(
    runtime: StepModel,
    frames: npt.NDArray[np.uint16],
    devices: int,
    *,
    max_batch: int,
    turns: int,
    repeats: int,
) -> list[tuple[float, float]]:
    """Per repeat: (CPU per frame of the whole turn, of Session.run alone), in seconds."""
    timed = _TimedSession(runtime._session)  # the bench's probe: the model's call alone
    runtime._session = timed
    engine = InferenceEngine(max_batch=max_batch)
    loop = asyncio.new_event_loop()
    got: list[InferenceResult] = []
    lanes = [engine.lane(Window(runtime), got.append, max_queue=4) for _ in range(devices)]
    for lane in lanes:
        lane._loop = loop  # results go to this loop, run between turns (not timed)
        engine._lanes.append(lane)
    offsets = [(i * 97) % len(frames) for i in range(devices)]
    seq = 0

    def turn() -> float:
        nonlocal seq
        for lane, offset in zip(lanes, offsets, strict=True):
            counts = frames[(offset + seq) % len(frames)]
            lane.submit(InferenceJob(seq, PairedFrame(counts, (seq, seq), (0, 0), 0)))
        seq += 1
        start = time.process_time()
        taken = engine._take_ready()  # what the engine's thread does in one turn
        for first in range(0, len(taken), engine.max_batch):
            engine._run_batch(taken[first : first + engine.max_batch])
        spent = time.process_time() - start
        loop.call_soon(loop.stop)
        loop.run_forever()  # deliver the results, as the daemon's loop would
        got.clear()
        return spent

    try:
        for _ in range(runtime.window + 8):  # warm the windows up, and onnxruntime's plans
            turn()
        out = []
        for _ in range(repeats):
            timed.cpu_s = 0.0
            total = sum(turn() for _ in range(turns))
            n = turns * devices
            out.append((total / n, timed.cpu_s / n))
        return out
    finally:
        runtime._session = timed._session
        loop.close()


def run_here(args: argparse.Namespace) -> dict[str, list[tuple[float, float]]]:
    runtime = open_step_model(args.model)  # either form, as the daemon
    kinds: dict[str, Callable[[], npt.NDArray[np.uint16]]] = {
        "sim": sim_frames,
        "random": random_frames,
    }
    results: dict[str, list[tuple[float, float]]] = {}
    for kind in args.frames:
        frames = kinds[kind]()
        for n in args.devices:
            key = f"{kind} {n}"
            results[key] = measure(
                runtime,
                frames,
                n,
                max_batch=args.max_batch,
                turns=max(1, args.frames_per_repeat // n),
                repeats=args.repeats,
            )
    return results


_CHILD = """
import runpy, sys
import __editable___scotti_0_1_0_finder as finder
root, here = sys.argv[1], sys.argv[2]
old = finder.MAPPING["scotti.models"].rsplit("/", 1)[0]
finder.MAPPING.update({k: root + v[len(old):] for k, v in finder.MAPPING.items()})
sys.argv = [here, *sys.argv[3:]]
runpy.run_path(here, run_name="__main__")
"""


def run_child(args: argparse.Namespace, root: Path | None) -> dict[str, Any]:
    """One round of ``run_here`` in a fresh process, on this checkout or ``root``'s code."""
    argv = [
        "--json",
        "--model",
        str(args.model),
        "--max-batch",
        str(args.max_batch),
        "--repeats",
        str(args.repeats),
        "--frames-per-repeat",
        str(args.frames_per_repeat),
        "--devices",
        *map(str, args.devices),
        "--frames",
        *args.frames,
    ]
    if root is None:
        cmd = [sys.executable, "-m", "scotti.daemon.tools.bench_inference", *argv]
    else:
        cmd = [sys.executable, "-c", _CHILD, str(root.resolve()), __file__, *argv]
    done = subprocess.run(cmd, check=False, capture_output=True, text=True)
    if done.returncode != 0:  # e.g. no editable install to point at another checkout
        last = (done.stderr.strip().splitlines() or ["no output"])[-1]
        msg = f"bench_inference: the run on {root or 'this checkout'} failed: {last}"
        raise SystemExit(msg)
    result: dict[str, Any] = json.loads(done.stdout.strip().splitlines()[-1])
    return result


def table(results: dict[str, dict[str, list[tuple[float, float]]]]) -> list[str]:
    lines = [
        "| code | frames | devices | CPU us/frame min | median | Session.run min | median "
        "| python min | median |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for code, by_key in results.items():
        for key, values in by_key.items():
            kind, n = key.split()
            total = np.array([t for t, _ in values]) * 1e6
            model = np.array([m for _, m in values]) * 1e6
            python = total - model
            cells = [f"{min(a):.0f} | {float(np.median(a)):.0f}" for a in (total, model, python)]
            lines.append(f"| {code} | {kind} | {n} | " + " | ".join(cells) + " |")
    return lines


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m scotti.daemon.tools.bench_inference")
    p.add_argument("--model", type=Path, default=DEFAULT_MODEL)
    p.add_argument("--devices", type=int, nargs="+", default=[1, 8, 32, 64])
    p.add_argument("--frames", nargs="+", choices=["sim", "random"], default=["sim", "random"])
    p.add_argument("--max-batch", type=int, default=8, help="the engine's (settings: 8)")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--frames-per-repeat", type=int, default=512)
    p.add_argument("--rounds", type=int, default=3, help="with --baseline: A/B rounds")
    p.add_argument("--baseline", type=Path, help="a checkout whose code to compare with")
    p.add_argument("--json", action="store_true", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if min(args.devices) < 1 or args.max_batch < 1 or args.repeats < 1:
        p.error("--devices, --max-batch and --repeats must be at least 1")
    if args.baseline is not None and not (args.baseline / "models").is_dir():
        p.error(f"--baseline {args.baseline}: not a checkout of this repository")
    if args.json:
        print(json.dumps(run_here(args)))
        return 0
    if args.baseline is None:
        results = {"this": run_here(args)}
    else:
        results = {"baseline": {}, "this": {}}
        for _ in range(args.rounds):  # interleaved: a busy spell weighs on both alike
            for code, root in (("baseline", args.baseline), ("this", None)):
                for key, values in run_child(args, root).items():
                    results[code].setdefault(key, []).extend(map(tuple, values))
    print(
        f"inference thread CPU per frame, {args.model.name}, max_batch {args.max_batch}, "
        f"load average {os.getloadavg()[0]:.1f}"
    )
    print("\n".join(table(results)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
