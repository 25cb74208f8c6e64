"""Benchmark: one daemon serving N insole pairs at 16 Hz against a real mosquitto.

For each N in ``--pairs``, N emulated receiver boards (random frames, both
feet, row blocks as the radio sends them) play into N pseudo-terminals from
a helper process, and one ``scotti-daemon`` subprocess reads them all through
a ``[[devices]]`` config. A subscriber in this process takes every pose and
measures what a consumer sees: receipt time minus the frame's last byte
(``predicted_for_mono_ns`` - 1/16 s, the same host clock). The daemon's own
``latency_ms`` (last byte -> publish) comes from the payload. The daemon's
CPU (100 % = one core) and peak RSS are sampled with psutil (the ``[bench]``
extra: ``pip install 'scotti[bench]'``), and from the daemon's start to the
end of the run its peak memory, threads and open descriptors, from which the
unit's MemoryMax, TasksMax and LimitNOFILE are set (docs/deploy.md). Each N runs with
the batched engine (``inference.batch = true``) and, with ``--modes``, one
model call per pair (``false``), and with ``--processes`` over several worker
processes (daemon/service/processes.py). A measurement, never a test.

    python -m scotti.daemon.tools.bench --pairs 1 2 4 8 16 32 64 [--seconds 20]
    python -m scotti.daemon.tools.bench --pairs 32 --processes 1 2 --modes batch
    python -m scotti.daemon.tools.bench --step-batches 1 2 4 8 16 32 64   # the model alone
"""

from __future__ import annotations

import argparse
import asyncio
import json
import multiprocessing
import os
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import aiomqtt
import numpy as np
from scotti.daemon.input.board_emulator import BoardEmulator
from scotti.daemon.service.counters import latency_summary
from scotti.daemon.settings import ConfigError, default_model_path
from scotti.daemon.tools.local_broker import Mosquitto
from scotti.firmware_protocol.framing import encode_packet
from scotti.firmware_protocol.packets import Foot, FrameRows
from scotti.models.contract import FRAME_COLS, FRAME_RATE_HZ, FRAME_ROWS, MAX_COUNT, SAMPLE_BITS

try:
    import psutil
except ImportError:  # the [bench] extra; main() says so
    _NO_PSUTIL = True
else:
    _NO_PSUTIL = False

PERIOD_NS = round(1e9 / FRAME_RATE_HZ)
ROWS_PER_PACKET = 8  # as the radio sends them: 4 packets per foot frame
GOAL_P99_MS = 1e3 / FRAME_RATE_HZ  # a subscriber should have each pose within one frame


def board_records(
    seconds: float, seed: int = 0, *, per_write: bool = False
) -> list[tuple[int, bytes]]:
    """What a receiver sends in ``seconds``: random frames, both feet, row blocks.

    ``per_write``: a foot frame's packets in one record (one write), as a USB
    receiver hands them over in one transfer; else one record per packet, 1 ms apart.
    """
    rng = np.random.default_rng(seed)
    records: list[tuple[int, bytes]] = []
    for i in range(round(seconds * FRAME_RATE_HZ)):
        t = i * PERIOD_NS
        for foot in (Foot.LEFT, Foot.RIGHT):
            counts = rng.integers(0, MAX_COUNT // 3, (FRAME_ROWS, FRAME_COLS), dtype=np.uint16)
            packets = [
                encode_packet(
                    FrameRows(
                        foot=foot,
                        seq=i % 65536,
                        board_clock_us=(i * PERIOD_NS // 1000) % (1 << 32),
                        rows=FRAME_ROWS,
                        cols=FRAME_COLS,
                        sample_bits=SAMPLE_BITS,
                        row_start=start,
                        samples=counts[start : start + ROWS_PER_PACKET],
                    )
                )
                for start in range(0, FRAME_ROWS, ROWS_PER_PACKET)
            ]
            if per_write:
                records.append((t, b"".join(packets)))
                t += 1_000_000
                continue
            for packet in packets:
                records.append((t, packet))
                t += 1_000_000
    return records


def percentiles(values: list[float]) -> str:
    s = latency_summary(values)
    if not s["n"]:
        return "no samples"
    return f"p50 {s['p50']:6.2f}  p90 {s['p90']:6.2f}  p99 {s['p99']:6.2f}  max {s['max']:6.2f} ms"


READY_TIMEOUT_S = 120.0  # longest wait for every pair's first pose (a loaded host is slow)


async def collect(
    broker: Mosquitto,
    seconds: float,
    warmup: float,
    topic: str = "scotti/+/pose",
    *,
    pairs: int = 0,
    measuring: threading.Event | None = None,
) -> list[dict[str, float]]:
    """Per pose message: the daemon's latency and last byte -> receipt, for ``seconds``.

    The measured seconds start ``warmup`` seconds after the subscription or, with
    ``pairs``, after every one of that many devices has published its first pose
    (the daemon started, each window filled); ``measuring`` is set then.
    """
    out: list[dict[str, float]] = []
    async with aiomqtt.Client(
        broker.host, broker.port, protocol=aiomqtt.ProtocolVersion.V5
    ) as client:
        await client.subscribe(topic)
        seen: set[str] = set()
        begin = time.monotonic() + (READY_TIMEOUT_S if pairs else warmup)
        end = begin + seconds

        async def read() -> None:
            nonlocal begin, end
            async for m in client.messages:
                received = time.monotonic_ns()
                now = time.monotonic()
                if pairs and len(seen) < pairs:
                    seen.add(str(m.topic))
                    if len(seen) == pairs:  # all ready: measure after the warm-up
                        begin, end = now + warmup, now + warmup + seconds
                if now >= end:
                    return
                if now < begin:
                    continue
                if measuring is not None:
                    measuring.set()
                pose = json.loads(bytes(m.payload))
                last_byte = pose["predicted_for_mono_ns"] - PERIOD_NS
                out.append({"publish": pose["latency_ms"], "receipt": (received - last_byte) / 1e6})

        async def until_end() -> None:
            while True:  # ``end`` moves once every pair is ready
                left = end - time.monotonic()
                if left <= 0:
                    return
                await asyncio.sleep(min(0.2, left))

        # Ends at ``end`` even while no pose comes (a daemon that fell silent).
        reader = asyncio.create_task(read())
        timer = asyncio.create_task(until_end())
        try:
            await asyncio.wait({reader, timer}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for task in (reader, timer):
                task.cancel()
            await asyncio.gather(reader, timer, return_exceptions=True)
    if measuring is not None:
        measuring.set()  # never ready: the sampler must not wait forever
    return out


@dataclass
class Peaks:
    """The most a daemon (its processes together) held at once since it started."""

    rss_mib: float = 0.0
    threads: int = 0  # what systemd's TasksMax counts
    fds: int = 0  # open descriptors, what LimitNOFILE bounds (per process: the largest)

    def update(self, tree: list[psutil.Process]) -> None:
        held = [_held(p) for p in tree]
        self.rss_mib = max(self.rss_mib, sum(h[0] for h in held) / 2**20)
        self.threads = max(self.threads, sum(h[1] for h in held))
        self.fds = max(self.fds, max((h[2] for h in held), default=0))


def sample_process(
    pid: int,
    seconds: float,
    warmup: float | threading.Event,
    others: tuple[int, ...] = (),
    peaks: Peaks | None = None,
) -> tuple[float, float, float]:
    """Mean CPU % (100 = one core) and peak RSS in MiB of ``pid`` and its children (a
    daemon with ``processes`` > 1: the supervisor and its workers, RSS summed) over
    ``seconds`` after ``warmup`` (seconds, or an event: once it is set), and the CPU %
    of ``others`` together (the bench's own load on the host). ``peaks``: updated from
    now (the daemon's start) to the end, the model load and every connection included."""
    proc = psutil.Process(pid)
    rest = [psutil.Process(p) for p in others]
    peaks = peaks if peaks is not None else Peaks()
    if isinstance(warmup, threading.Event):
        ready, until = warmup, time.monotonic() + READY_TIMEOUT_S + seconds
    else:
        ready, until = threading.Event(), time.monotonic() + warmup
    while not ready.wait(0.2) and time.monotonic() < until:
        peaks.update([proc, *_children(proc)])
    tree = [proc, *_children(proc)]  # workers are up once poses flow
    for p in (*tree, *rest):
        p.cpu_percent(None)
    rss, end = 0, time.monotonic() + seconds
    while time.monotonic() < end:
        time.sleep(0.5)
        rss = max(rss, sum(_rss(p) for p in tree))
        peaks.update(tree)
    cpu = sum(_cpu(p) for p in tree)
    return cpu, rss / 2**20, sum(p.cpu_percent(None) for p in rest)


def _children(proc: psutil.Process) -> list[psutil.Process]:
    try:
        return list(proc.children(recursive=True))
    except psutil.NoSuchProcess:
        return []


def _held(proc: psutil.Process) -> tuple[int, int, int]:
    """(RSS bytes, threads, open descriptors) of ``proc``; zeros once it is gone."""
    try:
        with proc.oneshot():
            return int(proc.memory_info().rss), proc.num_threads(), proc.num_fds()
    except psutil.NoSuchProcess:
        return 0, 0, 0


def _rss(proc: psutil.Process) -> int:
    try:
        return int(proc.memory_info().rss)
    except psutil.NoSuchProcess:  # a worker that died (it is started again)
        return 0


def _cpu(proc: psutil.Process) -> float:
    try:
        return float(proc.cpu_percent(None))
    except psutil.NoSuchProcess:
        return 0.0


def _play_boards(links: list[str], seconds: float, ready: object, stop: object) -> None:
    """The helper process: one emulated board per link, looping, until ``stop``."""
    records = board_records(seconds, per_write=True)  # looped
    boards = [BoardEmulator(records, Path(link), speed=1.0, loop=True) for link in links]
    for board in boards:
        board.start()
    ready.set()  # type: ignore[attr-defined]
    stop.wait()  # type: ignore[attr-defined]
    for board in boards:
        board.stop()


@dataclass(frozen=True)
class Row:
    pairs: int
    batch: bool
    processes: int  # the daemon's worker processes (1: all in one)
    published: int  # poses the subscriber got in the measured seconds
    seconds: float
    publish: dict[str, float | int]  # the daemon's latency_ms
    receipt: dict[str, float | int]  # last byte -> subscriber
    cpu: float  # the daemon (and its workers), % of one core
    rss: float  # the daemon (and its workers, summed), MiB
    bench_cpu: float  # the emulated boards, the subscriber and mosquitto, % of one core
    load: float  # 1-minute load average at the end
    peaks: Peaks  # from the daemon's start to the end of the run
    everything: bool = False  # remote control and (one process) the web and Foxglove servers

    @property
    def rate(self) -> float:
        """Poses per second per pair (16 = every frame)."""
        return self.published / self.seconds / self.pairs


def config_text(
    links: list[Path],
    broker: Mosquitto,
    batch: bool,
    max_batch: int = 8,
    processes: int = 1,
    *,
    everything: bool = False,
) -> str:
    """``everything``: remote control on and, in one process, the web and Foxglove
    servers on free ports (no clients), so that the peaks hold all the daemon opens."""
    tables = "".join(
        f'\n[[devices]]\nid = "pair{i:02d}"\nport = "{link}"\n' for i, link in enumerate(links)
    )
    control = "control = true\n" if everything else ""
    outputs = "[outputs]\nweb = 0\nfoxglove = 0\n" if everything and processes == 1 else ""
    return (
        f'log_level = "warning"\nprocesses = {processes}\n'
        f"[inference]\nbatch = {str(batch).lower()}\n"
        f"max_batch = {max_batch}\n"
        f'[mqtt]\nbroker = "{broker.url}"\n{control}{outputs}{tables}'
    )


def run_one(
    broker: Mosquitto,
    model: Path,
    pairs: int,
    batch: bool,
    seconds: float,
    warmup: float,
    max_batch: int = 8,
    processes: int = 1,
    everything: bool = False,
) -> Row:
    folder = Path(tempfile.mkdtemp(prefix="scotti-bench-"))
    links = [folder / f"tty{i:02d}" for i in range(pairs)]
    config = folder / "devices.toml"
    text = config_text(links, broker, batch, max_batch, processes, everything=everything)
    config.write_text(text)
    ctx = multiprocessing.get_context("spawn")
    ready, stop = ctx.Event(), ctx.Event()
    boards = ctx.Process(
        target=_play_boards, args=([str(p) for p in links], 8.0, ready, stop), daemon=True
    )
    boards.start()
    if not ready.wait(60):
        boards.kill()
        msg = "the emulated boards did not start"
        raise RuntimeError(msg)
    cmd = [sys.executable, "-m", "scotti.daemon.service.main", "--config", str(config)]
    cmd += ["--model", str(model)]
    env = {k: v for k, v in os.environ.items() if not k.startswith("SCOTTI_")}
    daemon = subprocess.Popen(cmd, env=env)
    try:
        others = (boards.pid or 0, os.getpid(), *_broker_pid(broker))
        peaks = Peaks()
        samples, (cpu, rss, bench_cpu) = asyncio.run(
            _measure(broker, daemon.pid, pairs, seconds, warmup, others, peaks)
        )
    finally:
        daemon.terminate()
        daemon.wait(30)
        stop.set()
        boards.join(15)
    return Row(
        pairs=pairs,
        batch=batch,
        processes=processes,
        published=len(samples),
        seconds=seconds,
        publish=latency_summary([s["publish"] for s in samples]),
        receipt=latency_summary([s["receipt"] for s in samples]),
        cpu=cpu,
        rss=rss,
        bench_cpu=bench_cpu,
        load=os.getloadavg()[0],
        peaks=peaks,
        everything=everything,
    )


def _broker_pid(broker: Mosquitto) -> tuple[int, ...]:
    proc = getattr(broker, "_proc", None)  # the local broker keeps its Popen private
    return (proc.pid,) if isinstance(proc, subprocess.Popen) else ()


async def _measure(
    broker: Mosquitto,
    pid: int,
    pairs: int,
    seconds: float,
    warmup: float,
    others: tuple[int, ...],
    peaks: Peaks,
) -> tuple[list[dict[str, float]], tuple[float, float, float]]:
    measuring = threading.Event()
    sampler = asyncio.to_thread(sample_process, pid, seconds, measuring, others, peaks)
    reader = collect(broker, seconds, warmup, pairs=pairs, measuring=measuring)
    samples, usage = await asyncio.gather(reader, sampler)
    return samples, usage


HEADER = (
    "| pairs | inference | poses/s per pair | publish p50 / p99 ms "
    "| subscriber p50 / p99 ms | daemon CPU % of a core | RSS MiB | bench's own CPU % "
    "| load avg |"
)


def table_row(r: Row) -> str:
    mode = "batched" if r.batch else "per pair"
    if r.processes > 1:
        mode += f", {r.processes} processes"
    p, s = r.publish, r.receipt
    return (
        f"| {r.pairs} | {mode} | {r.rate:.1f} | {p['p50']:.1f} / {p['p99']:.1f} "
        f"| {s['p50']:.1f} / {s['p99']:.1f} | {r.cpu:.0f} | {r.rss:.0f} | {r.bench_cpu:.0f} "
        f"| {r.load:.1f} |"
    )


PEAKS_HEADER = (
    "| pairs | processes | on | peak RSS MiB (all processes) | peak threads (all processes) "
    "| peak open descriptors (largest process) |"
)


def peaks_row(r: Row) -> str:
    p = r.peaks
    on = "MQTT only" if not r.everything else "control" if r.processes > 1 else "control, outputs"
    return f"| {r.pairs} | {r.processes} | {on} | {p.rss_mib:.0f} | {p.threads} | {p.fds} |"


def run(args: argparse.Namespace, model: Path) -> int:
    modes = [m == "batch" for m in args.modes]
    print(
        f"scotti-daemon bench: {args.seconds:.0f} s measured {args.warmup:.0f} s after every "
        f"pair's first pose, "
        f"{FRAME_RATE_HZ:.0f} Hz per pair, model {model.name}, max_batch {args.max_batch}, "
        f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f} at start, "
        f"nice {os.nice(0)}",
        flush=True,
    )
    print(HEADER)
    print("|" + "---|" * 9, flush=True)
    rows = []
    with Mosquitto() as broker:
        for pairs in args.pairs:
            for processes in args.processes:
                for batch in modes:
                    row = run_one(
                        broker,
                        model,
                        pairs,
                        batch,
                        args.seconds,
                        args.warmup,
                        args.max_batch,
                        processes,
                        args.everything,
                    )
                    rows.append(row)
                    print(table_row(row), flush=True)
    print("\nFrom the daemon's start to the end of each run (docs/deploy.md, the unit's limits):")
    print(PEAKS_HEADER)
    print("|" + "---|" * 6)
    for row in rows:
        print(peaks_row(row))
    return 0 if all(r.published for r in rows) else 1


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m scotti.daemon.tools.bench")
    p.add_argument("--pairs", type=int, nargs="+", default=[1], help="insole pairs, e.g. 1 8 32")
    p.add_argument("--seconds", type=float, default=20.0, help="measured seconds per run")
    p.add_argument(
        "--warmup", type=float, default=3.0,
        help="seconds from every pair's first pose to the measurement",
    )  # fmt: skip
    p.add_argument(
        "--modes", nargs="+", choices=("batch", "single"), default=["batch", "single"],
        help="batched engine (batch) and/or one model call per pair (single)",
    )  # fmt: skip
    p.add_argument("--max-batch", type=int, default=8, help="inference.max_batch (default 8)")
    p.add_argument(
        "--processes", type=int, nargs="+", default=[1], metavar="N",
        help="the daemon's worker processes, one run each (default 1: all pairs in one)",
    )  # fmt: skip
    p.add_argument(
        "--everything", action="store_true",
        help="also remote control and (with one process) the web and Foxglove servers, "
        "idle: the peaks a unit's limits must allow (docs/deploy.md)",
    )  # fmt: skip
    p.add_argument("--model", type=Path, help="ONNX step graph (default: the shipped one)")
    p.add_argument(
        "--step-batches", type=int, nargs="+", metavar="B",
        help="instead: time the model's step alone at these batch sizes (no daemon, no broker)",
    )  # fmt: skip
    args = p.parse_args(argv)
    if _NO_PSUTIL and not args.step_batches:
        print("bench: needs psutil: pip install 'scotti[bench]'", file=sys.stderr)
        return 1
    if (
        min(args.pairs) < 1
        or min(args.processes) < 1
        or args.seconds <= 0
        or args.warmup < 0
        or args.max_batch < 1
    ):
        print(
            "bench: --pairs, --processes and --max-batch must be >= 1, --seconds > 0, "
            "--warmup >= 0",
            file=sys.stderr,
        )
        return 2
    try:
        model = args.model or default_model_path()
    except ConfigError as exc:
        print(f"bench: {exc}", file=sys.stderr)
        return 78
    if args.step_batches:
        if min(args.step_batches) < 1:
            print("bench: --step-batches must be >= 1", file=sys.stderr)
            return 2
        from scotti.daemon.tools.step_costs import step_costs

        return step_costs(model, args.step_batches)
    return run(args, model)


if __name__ == "__main__":
    sys.exit(main())
