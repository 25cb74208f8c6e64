"""The no-hardware demo: board, broker, daemon and a live view on one machine.

A simulated receiver board plays a scene (``sim/scenes/demo.toml``) into a
pseudo-terminal; ``scotti-daemon --simulate`` reads it exactly as it would
read the real port and publishes to a local broker (mosquitto when
installed, else an embedded amqtt); the terminal view subscribes over MQTT
like any robot controller would. Ctrl-C (or ``--duration``) ends it all:
the daemon stops gracefully first (publishing ``offline``), then the broker.

    python -m scotti.daemon.tools.demo [--duration S] [--scene demo] [--model PATH]
"""

from __future__ import annotations

import argparse
import asyncio
import os
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

from scotti.daemon.errors import DaemonError
from scotti.daemon.input.simulated import resolve_scene
from scotti.daemon.settings import EX_CONFIG, ConfigError, default_model_path
from scotti.daemon.settings.mqtt import MqttSettings
from scotti.daemon.tools.local_broker import running_broker
from scotti.daemon.tools.viewer import ViewState, run_viewer
from scotti.daemon.waiting import wait_event

DEVICE = "demo"
FIRST_FRAME_LIMIT_S = 120.0  # with --duration: the longest wait for the first frame


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="scripts/demo", description=__doc__.split("\n\n")[0])
    p.add_argument(
        "--duration",
        type=float,
        default=0.0,
        help="seconds of frames shown, counted from the first one; 0 = until Ctrl-C",
    )
    p.add_argument("--scene", default="demo", help="scene name or TOML path (default demo)")
    p.add_argument("--model", type=Path, help="ONNX step graph (default: the shipped one)")
    p.add_argument("--speed", default="1", help="1 = real time, N times faster")
    p.add_argument(
        "--broker",
        choices=("auto", "mosquitto", "amqtt"),
        default="auto",
        help="auto: mosquitto if installed, else the embedded amqtt",
    )
    return p


async def run_demo(args: argparse.Namespace, model: Path) -> int:
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    state = ViewState()
    timer = None
    if args.duration > 0:
        timer = asyncio.create_task(_stop_after_frames(state, args.duration, stop))
    log_path = Path(tempfile.gettempdir()) / f"scotti-demo-daemon-{os.getpid()}.log"
    async with running_broker(args.broker) as (url, protocol):
        cmd = [
            sys.executable,
            "-m",
            "scotti.daemon.service.main",
            "--model",
            str(model),
            "--broker",
            url,
        ]
        cmd += ["--simulate", args.scene, "--speed", args.speed]
        cmd += ["--device-id", DEVICE, "--pressure"]
        env = {**os.environ, "SCOTTI_MQTT_PROTOCOL": protocol, "SCOTTI_LOG_LEVEL": "info"}
        with log_path.open("wb") as log:
            # Own session: Ctrl-C reaches the demo only, which stops the daemon in order.
            daemon = await asyncio.create_subprocess_exec(
                *cmd, stdout=log, stderr=subprocess.STDOUT, env=env, start_new_session=True
            )
        watcher = asyncio.create_task(_stop_when_exits(daemon, stop))
        settings = MqttSettings(broker=url, protocol=protocol, device_id=DEVICE)
        await run_viewer(settings, stop, device=DEVICE, state=state)
        watcher.cancel()
        if timer is not None:
            timer.cancel()
        code = await _stop_daemon(daemon)
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.remove_signal_handler(sig)
    print(f"demo: {state.frames_seen} frames shown; daemon exit {code}; its log: {log_path}")
    if code not in (0, -signal.SIGTERM):
        tail = log_path.read_text(errors="replace").strip().splitlines()[-5:]
        print("\n".join(f"  {line}" for line in tail), file=sys.stderr)
        return 1
    return 0


async def _stop_after_frames(state: ViewState, duration: float, stop: asyncio.Event) -> None:
    """Stop ``duration`` s after the first frame is shown.

    The clock starts at the first frame, not at launch: starting the broker
    and the daemon and rendering the scene take seconds, more on a busy or
    slow host, and a short ``--duration`` counted from launch once ended
    before anything was shown. With no frame in ``FIRST_FRAME_LIMIT_S`` the
    demo stops anyway (the summary says 0 frames shown).
    """
    if await wait_event(state.first_pose, FIRST_FRAME_LIMIT_S):
        await wait_event(stop, duration)
    stop.set()


async def _stop_when_exits(daemon: asyncio.subprocess.Process, stop: asyncio.Event) -> None:
    await daemon.wait()  # the daemon failed (or its scene ended): end the demo too
    stop.set()


async def _stop_daemon(daemon: asyncio.subprocess.Process) -> int:
    if daemon.returncode is None:
        daemon.send_signal(signal.SIGTERM)
        try:
            return await asyncio.wait_for(daemon.wait(), 15)
        except TimeoutError:
            daemon.kill()
    return await daemon.wait()


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        model = args.model or default_model_path()
    except ConfigError as exc:
        print(f"demo: {exc}", file=sys.stderr)
        return EX_CONFIG
    try:
        resolve_scene(args.scene)  # a wrong scene name is one line here, not a daemon's log
        return asyncio.run(run_demo(args, model))
    except DaemonError as exc:  # no such scene (SourceError), no broker (BrokerError)
        print(f"demo: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
