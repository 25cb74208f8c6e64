"""Benchmark: the daemon against the board emulator at 16 Hz and a real mosquitto.

Prints per-frame latency percentiles (the daemon's own ``latency_ms``: the
frame's last byte read from the pty to the publish; and last byte to a
subscriber's receipt, from ``predicted_for_mono_ns`` on the same host clock)
and the daemon's CPU % and RSS. A measurement, never a test.

    python -m scotti.daemon.tools.bench [--seconds 30] [--model PATH] [--threads 1]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import aiomqtt
import numpy as np
import psutil
from scotti.daemon.board_emulator import BoardEmulator
from scotti.daemon.counters import latency_summary
from scotti.daemon.settings import ConfigError, default_model_path
from scotti.daemon.tools.local_broker import Mosquitto
from scotti.firmware_protocol.framing import encode_packet
from scotti.firmware_protocol.packets import Foot, FrameRows
from scotti.models.contract import FRAME_COLS, FRAME_RATE_HZ, FRAME_ROWS, MAX_COUNT, SAMPLE_BITS

PERIOD_NS = round(1e9 / FRAME_RATE_HZ)
ROWS_PER_PACKET = 8  # as the radio sends them: 4 packets per foot frame


def board_records(seconds: float, seed: int = 0) -> list[tuple[int, bytes]]:
    """What a receiver sends in ``seconds``: random frames, both feet, row blocks."""
    rng = np.random.default_rng(seed)
    records: list[tuple[int, bytes]] = []
    for i in range(round(seconds * FRAME_RATE_HZ)):
        t = i * PERIOD_NS
        for foot in (Foot.LEFT, Foot.RIGHT):
            counts = rng.integers(0, MAX_COUNT // 3, (FRAME_ROWS, FRAME_COLS), dtype=np.uint16)
            for start in range(0, FRAME_ROWS, ROWS_PER_PACKET):
                packet = FrameRows(
                    foot=foot,
                    seq=i % 65536,
                    board_clock_us=(i * PERIOD_NS // 1000) % (1 << 32),
                    rows=FRAME_ROWS,
                    cols=FRAME_COLS,
                    sample_bits=SAMPLE_BITS,
                    row_start=start,
                    samples=counts[start : start + ROWS_PER_PACKET],
                )
                records.append((t, encode_packet(packet)))
                t += 1_000_000
    return records


def percentiles(values: list[float]) -> str:
    s = latency_summary(values)
    if not s["n"]:
        return "no samples"
    return f"p50 {s['p50']:6.2f}  p90 {s['p90']:6.2f}  p99 {s['p99']:6.2f}  max {s['max']:6.2f} ms"


async def collect(broker: Mosquitto, seconds: float, warmup: float) -> list[dict[str, float]]:
    """Per pose message: the daemon's latency and last byte -> receipt, after ``warmup``."""
    out: list[dict[str, float]] = []
    async with aiomqtt.Client(
        broker.host, broker.port, protocol=aiomqtt.ProtocolVersion.V5
    ) as client:
        await client.subscribe("scotti/bench/pose")
        start = time.monotonic()

        async def read() -> None:
            async for m in client.messages:
                received = time.monotonic_ns()
                if time.monotonic() - start < warmup:
                    continue
                pose = json.loads(bytes(m.payload))
                last_byte = pose["predicted_for_mono_ns"] - PERIOD_NS
                out.append({"publish": pose["latency_ms"], "receipt": (received - last_byte) / 1e6})

        # asyncio.timeout, not wait_for: on 3.11 wait_for can swallow its own cancel when
        # a message arrives at that moment, and the read loop would then never end.
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(seconds + warmup):
                await read()
    return out


def sample_process(pid: int, seconds: float, warmup: float) -> tuple[float, float]:
    """Mean CPU % (100 = one core) and peak RSS in MiB over ``seconds`` after ``warmup``."""
    proc = psutil.Process(pid)
    time.sleep(warmup)
    proc.cpu_percent(None)
    rss, end = 0, time.monotonic() + seconds
    while time.monotonic() < end:
        time.sleep(0.5)
        rss = max(rss, proc.memory_info().rss)
    return proc.cpu_percent(None), rss / 2**20


def run(args: argparse.Namespace, model: Path) -> int:
    warmup = 4.0  # the window fills in 2.5 s; onnxruntime settles
    records = board_records(args.seconds + warmup + 5)
    link = Path(tempfile.mkdtemp(prefix="scotti-bench-")) / "ttyBENCH"
    with Mosquitto() as broker:
        board = BoardEmulator(records, link, speed=1.0, loop=True)
        board.start()
        cmd = [sys.executable, "-m", "scotti.daemon.main", "--port", str(link)]
        cmd += ["--model", str(model), "--broker", broker.url, "--device-id", "bench"]
        cmd += ["--threads", str(args.threads), "--log-level", "warning"]
        env = {k: v for k, v in os.environ.items() if not k.startswith("SCOTTI_")}
        daemon = subprocess.Popen(cmd, env=env)
        try:
            loop_task = asyncio.run(_measure(broker, daemon.pid, args.seconds, warmup))
        finally:
            daemon.terminate()
            daemon.wait(15)
            board.stop()
    samples, (cpu, rss) = loop_task
    frames = len(samples)
    print(
        f"scotti-daemon bench: {args.seconds:.0f} s at {FRAME_RATE_HZ:.0f} Hz, model {model.name}"
    )
    print(f"  threads {args.threads}; frames published {frames}")
    print(f"  last byte -> publish:          {percentiles([s['publish'] for s in samples])}")
    print(f"  last byte -> subscriber got:   {percentiles([s['receipt'] for s in samples])}")
    print(f"  daemon CPU {cpu:.1f} % of one core, RSS {rss:.0f} MiB")
    return 0 if frames else 1


async def _measure(
    broker: Mosquitto, pid: int, seconds: float, warmup: float
) -> tuple[list[dict[str, float]], tuple[float, float]]:
    sampler = asyncio.to_thread(sample_process, pid, seconds, warmup)
    samples, usage = await asyncio.gather(collect(broker, seconds, warmup), sampler)
    return samples, usage


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m scotti.daemon.tools.bench")
    p.add_argument("--seconds", type=float, default=30.0, help="measured seconds")
    p.add_argument("--model", type=Path, help="ONNX step graph (default: the shipped one)")
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args(argv)
    try:
        model = args.model or default_model_path()
    except ConfigError as exc:
        print(f"bench: {exc}", file=sys.stderr)
        return 78
    return run(args, model)


if __name__ == "__main__":
    sys.exit(main())
