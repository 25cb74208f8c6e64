"""A new user's first hour with scotti-daemon, each path against real processes.

No broker yet (the daemon says so, again and again, and never claims to be
online before the broker took its status), mistakes on the command line (one
line, exit 78), the simulated board (loops continue the sequence numbers;
``--once`` ends), the local broker anyone can start.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from scotti.daemon.mqtt.schemas import Health
from scotti.daemon.tools.local_broker import Mosquitto
from scotti.firmware_protocol.session import SessionHeader, SessionWriter, read_session
from scotti.models.contract import WINDOW

from tests.support.broker import DaemonProcess, collect, payloads, start_daemon
from tests.support.sessions import write_synthetic_session

FRAMES = 120


def wait_for_log(daemon: DaemonProcess, pattern: str, timeout: float, count: int = 1) -> str:
    """The daemon's log once ``pattern`` (a regex) matches ``count`` lines in it."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        log = daemon.log
        if len(re.findall(pattern, log, re.M)) >= count:
            return log
        assert daemon.proc.poll() is None, f"the daemon exited; log:\n{log}"
        time.sleep(0.1)
    msg = f"no {count} x {pattern!r} in {timeout} s; log:\n{daemon.log}"
    raise AssertionError(msg)


@pytest.mark.mosquitto
@pytest.mark.slow
def test_without_a_broker_the_daemon_says_so_again_and_the_replay_waits(
    tmp_path: Path, tiny_model_path: Path
) -> None:
    session = write_synthetic_session(tmp_path / "s.scotti", frames=FRAMES)
    broker = Mosquitto()  # its port is chosen, nothing listens there yet
    args = ["--replay", str(session.path), "--speed", "max", "--model", str(tiny_model_path)]
    args += ["--broker", broker.url, "--device-id", "nobroker"]
    env = {"SCOTTI_MQTT_OUTAGE_WARNING_S": "1", "SCOTTI_MQTT_RECONNECT_MAX_S": "0.2"}
    daemon = start_daemon(args, tmp_path / "d.log", env=env)
    try:
        log = wait_for_log(daemon, r"^WARNING .*still unreachable after", 30, count=2)
        first = [ln for ln in log.splitlines() if ln.startswith("WARNING")]
        assert broker.url in first[0]
        assert "Connection refused" in first[0]
        assert f"local_broker --port {broker.port}" in first[0]  # what to do about it
        repeats = [ln for ln in first if "still unreachable after" in ln]
        assert all(broker.url in ln and "Connection refused" in ln for ln in repeats)
        assert "the replay waits for the broker" in log
        assert not re.search(r"status (online|degraded)", log)  # nothing acknowledged it
        with broker, collect(broker, "scotti/nobroker/#") as got:
            assert daemon.wait(60) == 0, daemon.log
            got.wait_for(lambda m: payloads(m, "health"), 10, "the last health")
        messages = got.snapshot()
    finally:
        if daemon.proc.poll() is None:
            daemon.proc.kill()
    log = daemon.log
    lines = log.splitlines()
    connected = next(i for i, ln in enumerate(lines) if "connected" in ln and "broker" in ln)
    said = [i for i, ln in enumerate(lines) if re.search(r"status (online|degraded)", ln)]
    assert said, log
    assert min(said) > connected  # a status is said once the broker has acknowledged it
    health = Health.model_validate(payloads(messages, "health")[-1])
    expected = FRAMES - WINDOW + 1
    assert health.published == expected  # the replay waited: nothing was dropped
    assert health.dropped == 0
    publish = health.pipeline["publish"]
    assert publish["broker_outages"] == 1
    assert publish["broker_unreachable_s"] >= 2.0
    assert "Connection refused" in publish["broker_last_error"]
    # One end-to-end latency: health.end_to_end (the pipeline's own counters have none).
    assert health.end_to_end.p50_ms is not None
    assert set(health.pipeline["latency_ms"]) == {"inference"}


@pytest.mark.mosquitto
def test_the_local_broker_tool_serves_until_ctrl_c_and_refuses_a_busy_port(
    tmp_path: Path,
) -> None:
    from scotti.daemon.tools.local_broker import free_port

    port = free_port()
    cmd = [sys.executable, "-m", "scotti.daemon.tools.local_broker", "--port", str(port)]
    with subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) as tool:
        try:
            assert tool.stdout is not None
            ready = tool.stdout.readline()
            assert f"listening on mqtt://127.0.0.1:{port}" in ready, ready
            busy = subprocess.run(cmd, capture_output=True, text=True, timeout=30, check=False)
            assert busy.returncode == 1
            assert busy.stderr.strip() == (
                f"local_broker: 127.0.0.1:{port} is in use: a broker already running there? "
                "scotti-daemon can use that one as it is"
            )
            # A real client goes through it: what a retained message says comes back.
            hello = [sys.executable, "-c", _ROUND_TRIP, str(port)]
            out = subprocess.run(hello, capture_output=True, text=True, timeout=30, check=False)
            assert out.stdout.strip() == "hello", out.stderr
        finally:
            tool.send_signal(signal.SIGINT)
            assert tool.wait(15) == 0


_ROUND_TRIP = """
import asyncio, sys
import aiomqtt

async def main():
    port = int(sys.argv[1])
    async with aiomqtt.Client("127.0.0.1", port) as client:
        await client.publish("t/hello", b"hello", qos=1, retain=True)
        await client.subscribe("t/#")
        async for message in client.messages:
            print(message.payload.decode())
            return

asyncio.run(main())
"""


def run_daemon(*args: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    exe = Path(sys.executable).with_name("scotti-daemon")
    env = {k: v for k, v in os.environ.items() if not k.startswith("SCOTTI_")}
    return subprocess.run(
        [str(exe), *args], capture_output=True, text=True, timeout=timeout, check=False, env=env
    )


def _header_only(path: Path) -> Path:
    header = SessionHeader(source="recorded", device="x")
    SessionWriter(path, header).close()
    return path


def _corrupt(path: Path) -> Path:
    """A session whose whole records are followed by a length no record has."""
    session = write_synthetic_session(path.with_suffix(".ok"), frames=4)
    path.write_bytes(session.path.read_bytes() + (1 << 30).to_bytes(4, "little") + b"junk")
    return path


MISTAKES: dict[str, tuple[Callable[[Path], list[str]], str]] = {
    "not a session": (
        lambda d: ["--replay", str(_text(d / "notes.txt"))],
        "config error: source: replay: {d}/notes.txt is not a session file (no SCOTSESS magic)",
    ),
    "empty": (
        lambda d: ["--replay", str(_empty(d / "empty.scotti"))],
        "config error: source: replay: {d}/empty.scotti is empty (0 bytes), not a session file",
    ),
    "cut before its header": (
        lambda d: ["--replay", str(_bytes(d / "cut.scotti", b"SCOTSE"))],
        "config error: source: replay: {d}/cut.scotti is a session file cut short before its "
        "header",
    ),
    "no packets": (
        lambda d: ["--replay", str(_header_only(d / "header.scotti"))],
        "error: replay: {d}/header.scotti holds no packet records: nothing to replay",
    ),
    "corrupt": (
        lambda d: ["--replay", str(_corrupt(d / "corrupt.scotti"))],
        "error: replay: {d}/corrupt.scotti is corrupt: record of 1073741824 bytes at offset",
    ),
    "missing": (
        lambda d: ["--replay", str(d / "missing.scotti")],
        "config error: source: replay file not found: {d}/missing.scotti",
    ),
    "once with a replay": (
        lambda d: ["--replay", str(write_synthetic_session(d / "s.scotti").path), "--once"],
        "config error: source: once: goes with --simulate (a replay plays once already)",
    ),
    "unknown option": (
        lambda d: ["--simulate", "demo", "--bogus"],
        "usage error: unrecognized arguments: --bogus (see scotti-daemon --help)",
    ),
    "not a number": (
        lambda d: ["--simulate", "demo", "--processes", "two"],
        "usage error: argument --processes: invalid int value: 'two' (see scotti-daemon --help)",
    ),
    "unknown scene": (
        lambda d: ["--simulate", "no-such-scene"],
        "error: scene 'no-such-scene': no such file and no shipped scene of that name",
    ),
}


def _text(path: Path) -> Path:
    path.write_text("hello\n")
    return path


def _empty(path: Path) -> Path:
    path.write_bytes(b"")
    return path


def _bytes(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


@pytest.mark.parametrize("mistake", list(MISTAKES))
def test_a_mistake_on_the_command_line_is_one_line_and_exit_78(
    mistake: str, tmp_path: Path, tiny_model_path: Path
) -> None:
    make_args, expected = MISTAKES[mistake]
    args = [*make_args(tmp_path), "--model", str(tiny_model_path)]
    out = run_daemon(*args, "--broker", "mqtt://127.0.0.1:1")
    assert out.returncode == 78, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1, out.stderr
    assert lines[0].startswith("scotti-daemon: " + expected.format(d=tmp_path)), lines[0]


@pytest.mark.mosquitto
def test_a_replay_cut_short_plays_its_whole_records_with_one_warning(
    mosquitto: Mosquitto, tmp_path: Path, tiny_model_path: Path
) -> None:
    session = write_synthetic_session(tmp_path / "whole.scotti", frames=FRAMES, labels=False)
    cut = tmp_path / "cut.scotti"
    cut.write_bytes(session.path.read_bytes()[:-100])  # the last record cut in two
    whole_records = len(read_session(cut).packets)
    assert whole_records == len(session.records) - 1
    with collect(mosquitto, "scotti/cut/#") as got:
        args = ["--replay", str(cut), "--speed", "max", "--model", str(tiny_model_path)]
        daemon = start_daemon(
            [*args, "--broker", mosquitto.url, "--device-id", "cut"], tmp_path / "d.log"
        )
        assert daemon.wait(60) == 0, daemon.log
        got.wait_for(lambda m: any(s["state"] == "offline" for s in payloads(m, "status")), 10)
    warnings = [ln for ln in daemon.log.splitlines() if ln.startswith("WARNING")]
    assert warnings == [
        f"WARNING scotti.daemon.input.sources: replay: {cut} ends inside a record (cut short): "
        f"replaying its {whole_records} whole packet records"
    ]
    health = Health.model_validate(payloads(got.snapshot(), "health")[-1])
    assert health.frames_in["left"] == FRAMES  # the cut record was the right foot's last
    assert health.published == health.predictions > 0


SHORT_SCENE = """
description = "a short squat for tests: 4.5 s"
seed = 3
rate = 16.0

[subject]
height_m = 1.75
mass_kg = 72.0
style_seed = 11

[[script]]
action = "squat"
duration_s = 4.0
stand_s = 0.5
"""


@dataclass(frozen=True)
class Scene:
    path: Path
    frames: int  # frames per foot in one play of it, as the simulator renders it


@pytest.fixture
def short_scene(tmp_path: Path) -> Scene:
    from scotti.daemon.input.simulated import render_scene_file

    path = tmp_path / "short.toml"
    path.write_text(SHORT_SCENE)
    render_scene_file(path, tmp_path / "rendered.scotti")
    feet = session_info(tmp_path / "rendered.scotti")["feet"]
    assert feet["left"]["frames"] == feet["right"]["frames"]
    return Scene(path, feet["left"]["frames"])


def session_info(path: Path) -> dict[str, Any]:
    cmd = [sys.executable, "-m", "scotti.cli.main", "session", "info", "--json", str(path)]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=60, check=True)
    data = json.loads(out.stdout)
    assert isinstance(data, dict)
    return data


@pytest.mark.mosquitto
@pytest.mark.slow
def test_a_recording_of_the_simulated_board_across_its_loops_reads_as_one_session(
    mosquitto: Mosquitto, short_scene: Scene, tmp_path: Path, tiny_model_path: Path
) -> None:
    recording = tmp_path / "looped.scotti"
    args = ["--simulate", str(short_scene.path), "--speed", "4", "--record", str(recording)]
    args += ["--model", str(tiny_model_path), "--broker", mosquitto.url, "--device-id", "loop"]
    daemon = start_daemon(args, tmp_path / "d.log")
    try:
        wait_for_log(daemon, r"status online", 60)
        time.sleep(2.5 * short_scene.frames / 16 / 4)  # 2.5 loops at speed 4
    finally:
        assert daemon.stop() == 0, daemon.log
    info = session_info(recording)
    assert info["assembler"]["restarts"] == 0, info
    for foot in ("left", "right"):
        feet = info["feet"][foot]
        assert feet["frames"] > 2 * short_scene.frames  # across two loop boundaries
        assert feet["gaps"] == 0
        assert feet["last_seq"] - feet["first_seq"] + 1 == feet["frames"]
    assert "restart" not in daemon.log
    assert "WARNING" not in daemon.log, daemon.log


@pytest.mark.mosquitto
@pytest.mark.slow
def test_simulate_once_plays_the_scene_once_and_exits_0_after_the_last_prediction(
    mosquitto: Mosquitto, short_scene: Scene, tmp_path: Path, tiny_model_path: Path
) -> None:
    frames = short_scene.frames
    args = ["--simulate", str(short_scene.path), "--once", "--speed", "4"]
    args += ["--model", str(tiny_model_path), "--broker", mosquitto.url, "--device-id", "once"]
    with collect(mosquitto, "scotti/once/#") as got:
        daemon = start_daemon(args, tmp_path / "d.log")
        assert daemon.wait(90) == 0, daemon.log
        got.wait_for(lambda m: any(s["state"] == "offline" for s in payloads(m, "status")), 10)
    messages = got.snapshot()
    health = Health.model_validate(payloads(messages, "health")[-1])
    assert health.frames_in == {"left": frames, "right": frames}  # once: no more, no less
    expected = list(range(WINDOW - 1, frames))  # every paired frame once the window is full
    assert [p["seq"] for p in payloads(messages, "pose")] == expected
    assert health.published == len(expected)
    last = payloads(messages, "status")[-1]
    assert (last["state"], last["reasons"]) == ("offline", ["stopped"])
    assert "the board has played everything" in daemon.log
    assert "WARNING" not in daemon.log, daemon.log


@pytest.mark.slow
def test_without_a_broker_the_other_outputs_show_it_and_the_log_claims_no_status(
    short_scene: Scene, tmp_path: Path, tiny_model_path: Path
) -> None:
    pytest.importorskip("foxglove")
    pytest.importorskip("mcap")
    from tests.support.outputs import read_mcap

    out = tmp_path / "live.mcap"
    nobody = Mosquitto()  # a free port, nothing listening
    args = ["--simulate", str(short_scene.path), "--once", "--speed", "4"]
    args += ["--model", str(tiny_model_path), "--broker", nobody.url, "--record-mcap", str(out)]
    daemon = start_daemon(args, tmp_path / "d.log")
    assert daemon.wait(90) == 0, daemon.log
    assert not re.search(r"status (online|degraded|offline)", daemon.log)  # none acknowledged
    messages, _, _ = read_mcap(out)
    reasons = [r for _, status in messages["/status"] for r in status.get("reasons", [])]
    assert any(r.startswith("broker unreachable (") and "refused" in r for r in reasons), reasons
