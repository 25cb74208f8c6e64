"""Benchmark: does the web view slow MQTT? End-to-end p99 with 0 and with N readers.

One emulated receiver board plays into a pseudo-terminal at 16 Hz; one
``scotti-daemon`` subprocess reads it, publishes to a real mosquitto and
serves ``--web``. A subscriber here measures each pose's last byte ->
receipt (``bench.collect``). The run is made twice: with no browser, then
with N clients reading the live feed (``/events``, every frame, from a
helper process that reads and discards), and prints both p99s and their
ratio. The goal (docs/outputs.md): the ratio within 1.10.

    python -m scotti.daemon.tools.web_clients_bench [--clients 1000] [--seconds 30]

The clients' process needs N descriptors (``ulimit -n``); the web server's
own process raises its limit as far as the hard limit allows. A
measurement, never a test: on a shared machine run it when the load is low,
and read the load average it prints.
"""

from __future__ import annotations

import argparse
import asyncio
import multiprocessing
import os
import selectors
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from scotti.daemon.outputs.yield_cpu import yield_cpu_to_others
from scotti.daemon.service.counters import latency_summary
from scotti.daemon.settings import ConfigError, default_model_path
from scotti.daemon.tools.bench import _play_boards, collect, config_text
from scotti.daemon.tools.local_broker import Mosquitto

GOAL_RATIO = 1.10  # MQTT p99 with readers over p99 without


@dataclass(frozen=True)
class Run:
    clients: int
    connected: int  # readers that got their feed's first event
    poses: int
    seconds: float
    receipt: dict[str, float | int]  # last byte -> subscriber, ms
    client_mb_s: float  # what the readers took, all together
    load: float


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _read_feeds(port: int, clients: int, ready: Any, stop: Any, result: Any, nice: bool) -> None:
    """The helper process: ``clients`` readers of ``/events``, reading and discarding.
    They stand for browsers on other machines: with ``--nice-readers`` in the idle
    scheduling class (nice 19 where there is none), so that on a small host they do
    not take the daemon's CPU as those would not."""
    if nice:
        yield_cpu_to_others()
    request = f"GET /events HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n".encode()
    selector = selectors.DefaultSelector()
    socks = []
    for _ in range(clients):
        s = socket.create_connection(("127.0.0.1", port), timeout=30)
        s.sendall(request)
        s.setblocking(False)
        selector.register(s, selectors.EVENT_READ)
        socks.append(s)
    greeted: set[int] = set()
    received = 0
    started = 0.0
    ready_at = time.monotonic() + 60
    while not stop.is_set():
        for key, _ in selector.select(0.2):
            sock: socket.socket = key.fileobj  # type: ignore[assignment]
            try:
                data = sock.recv(1 << 16)
            except BlockingIOError:
                continue
            except OSError:
                data = b""
            if not data:
                selector.unregister(sock)
                continue
            if started:
                received += len(data)
            elif b"hello" in data:
                greeted.add(sock.fileno())
        if not started and (len(greeted) == clients or time.monotonic() > ready_at):
            started = time.monotonic()
            result.put(len(greeted))
            ready.set()
    result.put(received / max(1e-9, time.monotonic() - started) / 1e6)
    for s in socks:
        s.close()


def run_one(
    broker: Mosquitto, model: Path, clients: int, seconds: float, warmup: float, nice: bool
) -> Run:
    folder = Path(tempfile.mkdtemp(prefix="scotti-webbench-"))
    link = folder / "tty00"
    port = free_port()
    config = folder / "daemon.toml"
    config.write_text(
        config_text([link], broker, batch=True)
        + f"\n[outputs]\nweb = {port}\nmax_connections = {clients + 16}\n"
    )
    ctx = multiprocessing.get_context("spawn")
    board_ready, board_stop = ctx.Event(), ctx.Event()
    boards = ctx.Process(
        target=_play_boards, args=([str(link)], 8.0, board_ready, board_stop), daemon=True
    )
    boards.start()
    if not board_ready.wait(60):
        boards.kill()
        raise RuntimeError("the emulated board did not start")
    cmd = [sys.executable, "-m", "scotti.daemon.service.main", "--config", str(config)]
    cmd += ["--model", str(model)]
    env = {k: v for k, v in os.environ.items() if not k.startswith("SCOTTI_")}
    daemon = subprocess.Popen(cmd, env=env)
    readers = None
    connected, mb_s = 0, 0.0
    try:
        if clients:
            _wait_listening(port, daemon)
            ready, stop, result = ctx.Event(), ctx.Event(), ctx.Queue()
            feeds = (port, clients, ready, stop, result, nice)
            readers = ctx.Process(target=_read_feeds, args=feeds)
            readers.start()
            ready.wait(120)
            connected = int(result.get(timeout=5))
        samples = asyncio.run(collect(broker, seconds, warmup, pairs=1))
        if readers is not None:
            stop.set()
            mb_s = float(result.get(timeout=30))
    finally:
        if readers is not None:
            readers.join(30)
        daemon.terminate()
        daemon.wait(30)
        board_stop.set()
        boards.join(15)
    return Run(
        clients=clients,
        connected=connected,
        poses=len(samples),
        seconds=seconds,
        receipt=latency_summary([s["receipt"] for s in samples]),
        client_mb_s=mb_s,
        load=os.getloadavg()[0],
    )


def _wait_listening(port: int, daemon: subprocess.Popen[bytes]) -> None:
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        if daemon.poll() is not None:
            raise RuntimeError(f"the daemon ended (exit {daemon.returncode})")
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=1):
                return
        except OSError:
            time.sleep(0.2)  # the daemon is still loading its model
    raise RuntimeError(f"nothing listens on {port}")


def row(r: Run) -> str:
    s = r.receipt
    return (
        f"| {r.clients} | {r.connected} | {r.poses / r.seconds:.1f} | {s['p50']:.1f} "
        f"| {s['p99']:.1f} | {s['max']:.1f} | {r.client_mb_s:.1f} | {r.load:.1f} |"
    )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m scotti.daemon.tools.web_clients_bench")
    p.add_argument("--clients", type=int, default=1000, help="web readers (default 1000)")
    p.add_argument("--seconds", type=float, default=30.0, help="measured seconds per run")
    p.add_argument("--warmup", type=float, default=3.0, help="seconds after the first pose")
    p.add_argument("--model", type=Path, help="ONNX step graph (default: the shipped one)")
    p.add_argument(
        "--nice-readers", action="store_true",
        help="run the readers in the idle scheduling class (stand-ins for browsers "
        "on other machines, which would not share the host's CPU)",
    )  # fmt: skip
    args = p.parse_args(argv)
    try:
        model = args.model or default_model_path()
    except ConfigError as exc:
        print(f"web_clients_bench: {exc}", file=sys.stderr)
        return 2
    print(
        f"web_clients_bench: 1 pair at 16 Hz, {args.seconds:.0f} s measured per run, "
        f"{os.cpu_count()} CPUs, readers {'idle class' if args.nice_readers else 'at nice 0'}, "
        f"load average {os.getloadavg()[0]:.1f} at start",
        flush=True,
    )
    print("| web readers | connected | poses/s | MQTT p50 ms | p99 ms | max ms | readers MB/s "
          "| load avg |")  # fmt: skip
    print("|" + "---|" * 8, flush=True)
    runs = []
    with Mosquitto() as broker:
        for clients in (0, args.clients):
            run = run_one(broker, model, clients, args.seconds, args.warmup, args.nice_readers)
            runs.append(run)
            print(row(runs[-1]), flush=True)
    base, loaded = runs[0].receipt["p99"], runs[1].receipt["p99"]
    ratio = loaded / base if base else float("inf")
    verdict = "within" if ratio <= GOAL_RATIO else "beyond"
    print(
        f"MQTT end-to-end p99: {base:.1f} ms with no reader, {loaded:.1f} ms with "
        f"{args.clients}: ratio {ratio:.2f} ({verdict} the goal of {GOAL_RATIO:.2f})"
    )
    return 0 if runs[0].poses and runs[1].poses else 1


if __name__ == "__main__":
    sys.exit(main())
