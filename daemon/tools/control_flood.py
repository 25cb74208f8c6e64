"""Does a flood of remote-control requests slow the predictions? A measurement.

One ``scotti-daemon --control`` replays random insole frames at 16 Hz into a
real mosquitto; a subscriber here takes every pose. The run has three
windows of ``--seconds`` each: quiet, then a flood of ``--rate`` requests a
second on ``cmd/event/mark`` (valid ones, each asking for a reply and an event,
the most a request can make the daemon do, sent from another process at QoS 0),
then quiet again. Per window: poses received, the daemon's ``latency_ms``
(frame's last byte -> handed to the MQTT client) and what a subscriber sees
(receipt minus the frame's last byte, same host clock), p50 / p99 / max; and
the daemon's CPU time in the window (100 % = one core; Linux, from /proc); and
the daemon's ``health.pipeline.control`` counts at the end.

With ``--no-control`` the daemon runs without remote control: the flood goes
to the broker and no further (nobody subscribes to it), which is what the
flood costs the host (the flooding process and the broker) without the daemon.

    python -m scotti.daemon.tools.control_flood [--seconds 10] [--rate 1000] [--json]
    python -m scotti.daemon.tools.control_flood --no-control
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import multiprocessing
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import aiomqtt
from scotti.daemon.service.counters import latency_summary
from scotti.daemon.settings import ConfigError, default_model_path
from scotti.daemon.tools.bench import board_records
from scotti.daemon.tools.local_broker import Mosquitto
from scotti.firmware_protocol.session import SessionHeader, SessionWriter
from scotti.models.contract import FRAME_RATE_HZ

DEVICE = "flood"
# The windows start a second after the first pose arrives (the daemon's start and the
# model's 40-frame window take seconds, more on a loaded host), at most this late.
STARTUP_MAX_S = 60.0
PERIOD_MS = 1e3 / FRAME_RATE_HZ
WINDOWS = ("quiet", "flood", "after")


def _flood(host: str, port: int, rate: float, seconds: float) -> None:
    """Another process: ``rate`` event/mark requests a second for ``seconds``, QoS 0."""
    import paho.mqtt.client as paho
    from paho.mqtt.enums import CallbackAPIVersion
    from paho.mqtt.packettypes import PacketTypes
    from paho.mqtt.properties import Properties

    client = paho.Client(CallbackAPIVersion.VERSION2, protocol=paho.MQTTv5)
    client.connect(host, port)
    client.loop_start()
    props = Properties(PacketTypes.PUBLISH)  # type: ignore[no-untyped-call]
    props.ResponseTopic = f"scotti/{DEVICE}/reply/flooder"
    topic = f"scotti/{DEVICE}/cmd/event/mark"
    start = time.monotonic()
    sent = 0
    while (now := time.monotonic()) - start < seconds:
        due = int((now - start) * rate)
        while sent < due:
            payload = json.dumps({"label": f"flood {sent}"}).encode()
            client.publish(topic, payload, qos=0, properties=props)
            sent += 1
        time.sleep(0.005)
    client.loop_stop()
    client.disconnect()


async def _subscribe(
    broker: Mosquitto,
    stop: asyncio.Event,
    first: asyncio.Event,
    poses: list[tuple[float, float, float]],
    health: list[Any],
) -> None:
    """Poses (arrival s, latency ms, ms since the frame's last byte) and health until ``stop``;
    ``first`` is set when the first pose arrives."""
    async with aiomqtt.Client(
        broker.host, broker.port, protocol=aiomqtt.ProtocolVersion.V5
    ) as client:
        await client.subscribe(f"scotti/{DEVICE}/pose", qos=0)
        await client.subscribe(f"scotti/{DEVICE}/health", qos=1)

        async def read() -> None:
            async for message in client.messages:
                now_ns = time.monotonic_ns()
                data = json.loads(bytes(message.payload))
                if message.topic.value.endswith("/health"):
                    health.append(data)
                    continue
                last_byte_ns = data["predicted_for_mono_ns"] - PERIOD_MS * 1e6
                seen_ms = (now_ns - last_byte_ns) / 1e6
                poses.append((now_ns / 1e9, data["latency_ms"], seen_ms))
                first.set()

        reader = asyncio.create_task(read())
        await stop.wait()
        reader.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await reader


def _cpu_s(pid: int) -> float | None:
    """User + system CPU seconds of process ``pid`` so far (Linux), else None."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _summary(values: list[float]) -> dict[str, float]:
    s = latency_summary(values)
    return {k: round(float(s[k]), 2) for k in ("p50", "p99", "max")} if values else {}


def run(
    seconds: float,
    rate: float,
    model: Path | None = None,
    log_path: Path | None = None,
    *,
    control: bool = True,
) -> dict[str, Any]:
    """The three windows' figures and the daemon's control counts (see the module text)."""
    model = model or default_model_path()
    total = STARTUP_MAX_S + 3 * seconds + 3.0
    with tempfile.TemporaryDirectory(prefix="scotti-flood-") as tmp, Mosquitto() as broker:
        session = Path(tmp) / "random.scotti"
        with SessionWriter(session, SessionHeader(source="simulated", device=DEVICE)) as writer:
            for t_ns, data in board_records(total, per_write=True):
                writer.write_packet(t_ns + 1_000_000_000, data)
        env = {k: v for k, v in os.environ.items() if not k.startswith("SCOTTI_")}
        env |= {"SCOTTI_MQTT_CONTROL_DIR": tmp, "SCOTTI_MQTT_HEALTH_INTERVAL_S": "1"}
        log_file = (log_path or Path(tmp) / "daemon.log").open("wb")
        exe = Path(sys.executable).with_name("scotti-daemon")
        args = ["--replay", str(session), "--model", str(model), "--broker", broker.url]
        args += ["--device-id", DEVICE, *(["--control"] if control else [])]
        daemon = subprocess.Popen(
            [str(exe), *args], stdout=log_file, stderr=subprocess.STDOUT, env=env
        )
        poses: list[tuple[float, float, float]] = []
        health: list[Any] = []
        windows: dict[str, float] = {}
        flooder = multiprocessing.get_context("spawn").Process(
            target=_flood, args=(broker.host, broker.port, rate, seconds), daemon=True
        )

        cpu: dict[str, float | None] = {}

        async def measure() -> None:
            stop, first = asyncio.Event(), asyncio.Event()
            listen = asyncio.create_task(_subscribe(broker, stop, first, poses, health))
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(first.wait(), STARTUP_MAX_S)
            base = time.monotonic() + 1.0
            windows.update({name: base + i * seconds for i, name in enumerate(WINDOWS)})
            for name in WINDOWS:
                await asyncio.sleep(max(0.0, windows[name] - time.monotonic()))
                cpu[name] = _cpu_s(daemon.pid)
                if name == "flood":
                    flooder.start()
            await asyncio.sleep(max(0.0, windows[WINDOWS[-1]] + seconds - time.monotonic()))
            cpu["end"] = _cpu_s(daemon.pid)
            # The counts come from a health message sent after the flood has ended (a
            # flooder started late on a loaded host floods past its window).
            await asyncio.to_thread(flooder.join, seconds + 30)
            seen = len(health)
            for _ in range(100):
                if len(health) > seen + 1:
                    break
                await asyncio.sleep(0.05)
            stop.set()
            await listen

        try:
            asyncio.run(measure())
        finally:
            flooder.join(seconds + 10)
            daemon.terminate()
            exit_code = daemon.wait(30)
            log_file.close()
    out: dict[str, Any] = {
        "seconds": seconds,
        "rate": rate,
        "control": control,
        "daemon_exit": exit_code,
    }
    next_mark = dict(zip(WINDOWS, [*WINDOWS[1:], "end"], strict=True))  # where a window ends
    for name in WINDOWS:
        lo, hi = windows.get(name, 0.0), windows.get(name, 0.0) + seconds
        inside = [p for p in poses if lo <= p[0] < hi]
        before, after = cpu.get(name), cpu.get(next_mark[name])
        out[name] = {
            "poses": len(inside),
            "cpu_percent": None
            if before is None or after is None
            else round(100 * (after - before) / seconds, 1),
            "latency_ms": _summary([p[1] for p in inside]),
            "subscriber_ms": _summary([p[2] for p in inside]),
        }
    out["counts"] = (health[-1]["pipeline"].get("control") if health else None) or {}
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m scotti.daemon.tools.control_flood")
    parser.add_argument("--seconds", type=float, default=10.0, help="each window (default 10)")
    parser.add_argument("--rate", type=float, default=1000.0, help="requests/s (default 1000)")
    parser.add_argument("--model", type=Path, help="step graph (default: the shipped one)")
    parser.add_argument(
        "--no-control", dest="control", action="store_false", help="the daemon without --control"
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args(argv)
    try:
        result = run(args.seconds, args.rate, args.model, control=args.control)
    except ConfigError as exc:
        print(f"control_flood: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    mode = "with --control" if args.control else "without --control"
    print(
        f"{args.rate:g} requests/s for {args.seconds:g} s, daemon {mode}; "
        f"exit {result['daemon_exit']}"
    )
    print(
        f"{'window':8} {'poses':>6} {'cpu %':>6}  latency_ms p50/p99/max   "
        "subscriber_ms p50/p99/max"
    )
    for name in WINDOWS:
        w = result[name]
        lat, sub = w["latency_ms"], w["subscriber_ms"]
        fmt = "{p50:6.2f} {p99:6.2f} {max:7.2f}"
        cpu_shown = "-" if w["cpu_percent"] is None else f"{w['cpu_percent']:.1f}"
        print(
            f"{name:8} {w['poses']:>6} {cpu_shown:>6}  {fmt.format(**lat) if lat else '-':22}  "
            f"{fmt.format(**sub) if sub else '-'}"
        )
    print("health.pipeline.control:", json.dumps(result["counts"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
