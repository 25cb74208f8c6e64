"""CPU per pair-frame on the way from serial bytes to paired frames (no model, no MQTT).

Two measurements, each in CPU microseconds of this process (``time.process_time``)
per paired frame out, over a byte stream laid out as the radio sends it (8-row
FRAME_ROWS blocks, 4 per foot frame, both feet, 16 Hz):

- ``path``: ``FramePath.feed`` alone (decode, assemble, pair);
- ``consume``: the daemon's ``Pipeline`` reading a live in-memory source: the path
  plus the pipeline's per-chunk and per-pair work (counters, state, the hand-off
  to inference; the inference lane here takes jobs and runs nothing);
- ``consume ... serial``: the same pipeline reading a ``SerialSource`` on a
  pseudo-terminal that the board emulator writes a foot frame into every 1 ms
  (the event loop thread's CPU only: ``time.thread_time``).

Frames are ``insole`` (a simulated squat scene through the realistic insole: mostly
zeros, as a real pressure map) or ``random`` (what ``bench.board_records`` sends);
chunks are ``write`` (a foot frame's 4 packets in one read, as a USB receiver
hands them over) or ``packet`` (one packet per read).

    python -m scotti.daemon.tools.bench_frame_path [--seconds 60] [--rounds 7]
    python -m scotti.daemon.tools.bench_frame_path --baseline /tmp/wt-base   # A/B
    python -m scotti.daemon.tools.bench_frame_path --fallback-cobs   # no [fast] extra

``--baseline DIR``: DIR is another checkout of this repository (``git worktree add
/tmp/wt-base <commit>``); each round runs it and this checkout in fresh
subprocesses, one after the other, so that a busy host weighs on both alike.
A measurement, never a test.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import pickle
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import AsyncGenerator
from importlib import resources
from pathlib import Path
from typing import Any, Final

import numpy as np

PERIOD_NS: Final = 62_500_000  # 16 Hz
ROWS_PER_PACKET: Final = 8
SERIAL_GAP_NS: Final = 1_000_000  # between the emulated board's writes
SCENE: Final = "squat.toml"  # sim/scenes: six squats with standing between
Records = list[tuple[int, bytes]]


def insole_frames() -> np.ndarray:
    """(N, 2, 32, 22) uint16 counts of a simulated scene through the realistic insole."""
    from scotti.firmware_protocol.frame_path import stream_pairs
    from scotti.firmware_protocol.session import PacketRecord, SessionReader
    from scotti.sim.corpus import render_scene
    from scotti.sim.scene import load_scene

    scene = load_scene(Path(str(resources.files("scotti.sim.scenes").joinpath(SCENE))))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "scene.scotti"
        render_scene(scene, path)
        with SessionReader(path) as reader:
            chunks = [(r.t_ns, r.data) for r in reader if isinstance(r, PacketRecord)]
    counts = np.stack([pair.counts for pair in stream_pairs(chunks)])
    return counts.reshape(len(counts), 32, 2, 22).transpose(0, 2, 1, 3).copy()


def random_frames(frames: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.integers(0, 4095 // 3, (frames, 2, 32, 22), dtype=np.uint16)


def byte_stream(frames: np.ndarray, count: int, per_write: bool) -> Records:
    """``count`` pair-frames (``frames`` looped) as reads of a receiver's serial port."""
    from scotti.firmware_protocol.framing import encode_packet
    from scotti.firmware_protocol.packets import Foot, FrameRows

    records: Records = []
    for i in range(count):
        t = i * PERIOD_NS
        for foot in (Foot.LEFT, Foot.RIGHT):
            counts = frames[i % len(frames), foot]
            packets = [
                encode_packet(
                    FrameRows(
                        foot, i % 65536, (i * PERIOD_NS // 1000) % (1 << 32), 32, 22, 12,
                        start, counts[start : start + ROWS_PER_PACKET],
                    )
                )
                for start in range(0, 32, ROWS_PER_PACKET)
            ]  # fmt: skip
            reads = [b"".join(packets)] if per_write else packets
            for data in reads:
                records.append((t, data))
                t += 1_000_000
    return records


def time_path(records: Records) -> tuple[float, int]:
    """CPU seconds of ``FramePath.feed`` over ``records`` (then ``end``), and pairs out."""
    from scotti.firmware_protocol.frame_path import FramePath

    path = FramePath()
    feed = path.feed
    pairs = 0
    start = time.process_time()
    for t_ns, data in records:
        pairs += len(feed(data, t_ns))
    pairs += len(path.end())
    return time.process_time() - start, pairs


class _Lane:
    """An inference lane that takes every job and runs nothing."""

    def __init__(self, max_queue: int) -> None:
        self.max_queue = max_queue
        self.in_flight = 0
        self.jobs = 0

    def start(self) -> None: ...

    async def stop(self) -> None: ...

    async def wait_below(self, depth: int) -> None: ...

    def submit(self, job: Any) -> int:
        self.jobs += 1
        return 0


class _Engine:
    def __init__(self) -> None:
        self.lanes: list[_Lane] = []

    def lane(self, window: Any, on_result: Any, max_queue: int) -> _Lane:
        self.lanes.append(_Lane(max_queue))
        return self.lanes[-1]


class _Source:
    """A live source reading ``records`` from memory."""

    name = "bench"
    live = True

    def __init__(self, records: Records) -> None:
        self.records = records

    async def stream(self) -> AsyncGenerator[Any, None]:
        from scotti.daemon.input.sources import SourceEvent

        yield SourceEvent("connected", "bench")
        for record in self.records:
            yield record


def time_consume(records: Records, runtime: Any) -> tuple[float, int]:
    """CPU seconds of a ``Pipeline`` consuming ``records``, and pairs handed to inference."""
    from scotti.daemon.frames.pipeline import Pipeline
    from scotti.daemon.service.counters import Counters

    engine: Any = _Engine()  # stands in for an InferenceEngine: duck-typed
    pipeline = Pipeline(_Source(records), runtime, Counters(), engine=engine)

    async def go() -> float:
        start = time.process_time()
        await pipeline.run(lambda _: None, lambda _: None, asyncio.Event())
        return time.process_time() - start

    took = asyncio.run(go())
    return took, engine.lanes[0].jobs


def time_serial(records: Records, runtime: Any) -> tuple[float, int]:
    """CPU seconds of the event loop's thread (``time.thread_time``) while a ``Pipeline``
    reads ``records`` from a ``SerialSource`` on a pseudo-terminal that a board emulator
    (another thread, not counted) writes one record into every ``SERIAL_GAP_NS``."""
    from scotti.daemon.frames.pipeline import Pipeline
    from scotti.daemon.input.board_emulator import BoardEmulator
    from scotti.daemon.input.sources import SerialSource
    from scotti.daemon.service.counters import Counters

    paced = [(i * SERIAL_GAP_NS, data) for i, (_, data) in enumerate(records)]
    engine: Any = _Engine()  # stands in for an InferenceEngine: duck-typed
    with tempfile.TemporaryDirectory() as tmp, BoardEmulator(paced, Path(tmp) / "tty") as board:
        source = SerialSource(str(board.link), stall_s=0.3, played=board.finished)
        pipeline = Pipeline(source, runtime, Counters(), engine=engine)

        async def go() -> float:
            start = time.thread_time()
            await pipeline.run(lambda _: None, lambda _: None, asyncio.Event())
            return time.thread_time() - start

        took = asyncio.run(go())
    return took, engine.lanes[0].jobs


def measure(workloads: dict[str, Records], passes: int) -> dict[str, list[float]]:
    """Microseconds of CPU per pair-frame, per workload and pass."""
    from scotti.daemon.settings import default_model_path
    from scotti.models.kv_streaming import open_step_model

    runtime = open_step_model(default_model_path())
    out: dict[str, list[float]] = {}
    for _ in range(passes):
        for name, records in workloads.items():
            if name.endswith(" serial"):
                seconds, pairs = time_serial(records, runtime)
                out.setdefault(f"consume {name}", []).append(seconds * 1e6 / pairs)
                continue
            seconds, pairs = time_path(records)
            out.setdefault(f"path {name}", []).append(seconds * 1e6 / pairs)
            seconds, pairs = time_consume(records, runtime)
            out.setdefault(f"consume {name}", []).append(seconds * 1e6 / pairs)
    return out


def _run_child(
    root: Path | None, data: Path, passes: int, fallback_cobs: bool
) -> dict[str, list[float]]:
    env = dict(os.environ)
    with tempfile.TemporaryDirectory() as tmp:
        if root is not None:  # ``scotti`` is a namespace package: a link to the checkout is it
            (Path(tmp) / "scotti").symlink_to(root.resolve())
            env["PYTHONPATH"] = tmp + os.pathsep + env.get("PYTHONPATH", "")
        # This file's code over the side's own modules (run_path: no folder put on sys.path).
        args = ["--child", str(data), "--passes", str(passes)]
        args += ["--fallback-cobs"] if fallback_cobs else []
        code = f"import runpy, sys; sys.argv[1:] = {args!r}; "
        code += f"runpy.run_path({__file__!r}, run_name='__main__')"
        cmd = [sys.executable, "-c", code]
        done = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
    if done.returncode:
        raise SystemExit(f"bench child failed:\n{done.stderr}")
    result: dict[str, list[float]] = json.loads(done.stdout.strip().splitlines()[-1])
    return result


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m scotti.daemon.tools.bench_frame_path")
    parser.add_argument("--seconds", type=float, default=60.0, help="stream length (16 Hz)")
    parser.add_argument("--rounds", type=int, default=7, help="subprocess rounds (each side)")
    parser.add_argument("--passes", type=int, default=2, help="passes per round")
    parser.add_argument("--baseline", type=Path, help="another checkout to compare with")
    parser.add_argument(
        "--fallback-cobs",
        action="store_true",
        help="decode COBS without the compiled package (a host without the [fast] extra)",
    )
    parser.add_argument("--child", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.fallback_cobs:
        from scotti.firmware_protocol import cobs

        cobs._compiled = None
    if args.child is not None:
        workloads = pickle.loads(args.child.read_bytes())
        print(json.dumps(measure(workloads, args.passes)))
        return 0
    count = round(args.seconds / (PERIOD_NS / 1e9))
    frames = {"insole": insole_frames(), "random": random_frames(count)}
    workloads = {
        f"{kind} {chunks}": byte_stream(f, count, per_write=chunks == "write")
        for kind, f in frames.items()
        for chunks in ("write", "packet")
    }
    # A serial port, a foot frame per write (the insole frames; one write every 1 ms)
    workloads["insole serial"] = workloads["insole write"]
    sides: dict[str, Path | None] = {"this": None}
    if args.baseline is not None:
        sides = {"baseline": args.baseline, "this": None}
    results: dict[str, dict[str, list[float]]] = {side: {} for side in sides}
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "workloads.pickle"
        data.write_bytes(pickle.dumps(workloads))
        for _ in range(args.rounds):
            for side, root in sides.items():
                done = _run_child(root, data, args.passes, args.fallback_cobs)
                for name, values in done.items():
                    results[side].setdefault(name, []).extend(values)
    decoder = "fallback (pure Python)" if args.fallback_cobs else "compiled if installed"
    print(
        f"bytes -> paired frames, {count} pair-frames per pass, {args.rounds} rounds x "
        f"{args.passes} passes, COBS {decoder}, load average {os.getloadavg()[0]:.1f}"
    )
    print("CPU us per pair-frame (time.process_time), min / median")
    print("| workload | " + " | ".join(sides) + " |")
    print("|---|" + "---|" * len(sides))
    for name in results["this"]:
        cells = []
        for side in sides:
            values = results[side][name]
            cells.append(f"{min(values):.1f} / {statistics.median(values):.1f}")
        print(f"| {name} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
