"""scotti-daemon as a subprocess against a real mosquitto: replay and a pty board."""

from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import socket
import subprocess
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scotti.daemon.input.board_emulator import BoardEmulator
from scotti.daemon.mqtt.schemas import Action, Health, Info, Pose, Progress, Status
from scotti.daemon.tools.local_broker import Mosquitto
from scotti.firmware_protocol.session import read_session
from scotti.models.contract import FRAME_COLS, FRAME_ROWS, KEYPOINTS, WINDOW

from tests.support.broker import Received, collect, payloads, start_daemon
from tests.support.sessions import SyntheticSession, write_synthetic_session

pytestmark = [pytest.mark.mosquitto, pytest.mark.slow]

FRAMES = 120
STAMP_KEYS = ("seq", "device_seq", "device_time_us", "host_wall_ns", "host_mono_ns")
DOCS = Path(__file__).parent.parent / "docs"


@pytest.fixture
def session(tmp_path: Path) -> SyntheticSession:
    return write_synthetic_session(tmp_path / "e2e.scotti", frames=FRAMES)


def daemon_args(broker: Mosquitto, model: Path, device: str, *source: str) -> list[str]:
    return [*source, "--model", str(model), "--broker", broker.url, "--device-id", device]


def offline(msgs: list[Received]) -> bool:
    return any(s["state"] == "offline" for s in payloads(msgs, "status"))


def replay(
    broker: Mosquitto,
    session: Path,
    model: Path,
    tmp_path: Path,
    device: str,
    *extra: str,
    **env: str,
) -> list[Received]:
    with collect(broker, f"scotti/{device}/#") as got:
        args = daemon_args(broker, model, device, "--replay", str(session), "--speed", "8")
        args += extra
        daemon = start_daemon(args, tmp_path / f"{device}.log", env=env)
        assert daemon.wait(60) == 0, daemon.log
        got.wait_for(offline, 5, "status offline")
    return got.snapshot()


def prediction_view(msgs: list[Received]) -> dict[int, tuple[Any, ...]]:
    """seq -> what the model said (no clocks): the part that must be reproducible."""
    pose = {p["seq"]: p["keypoints"] for p in payloads(msgs, "pose")}
    action = {a["seq"]: a["probabilities"] for a in payloads(msgs, "action")}
    prog = {p["seq"]: (p["progress"], p["repetition"]) for p in payloads(msgs, "progress")}
    return {s: (pose[s], action[s], prog[s]) for s in pose}


def test_replay_publishes_joinable_valid_frames_deterministically(
    mosquitto: Mosquitto, session: SyntheticSession, tiny_model_path: Path, tmp_path: Path
) -> None:
    notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    notify.bind(str(tmp_path / "notify"))
    notify.settimeout(0.5)
    notes: list[str] = []  # read as they come: a datagram socket queues only ~10

    def listen() -> None:
        while "STOPPING=1" not in notes:
            with contextlib.suppress(TimeoutError):
                notes.append(notify.recv(4096).decode())

    listener = threading.Thread(target=listen, daemon=True)
    listener.start()
    env = {"NOTIFY_SOCKET": str(tmp_path / "notify"), "WATCHDOG_USEC": "200000"}
    first = replay(mosquitto, session.path, tiny_model_path, tmp_path, "e2e-a", **env)
    listener.join(5)
    notify.close()

    frames = {name: [m for m in first if m.topic.endswith("/" + name)] for name in ("pose",)}
    expected = list(range(WINDOW - 1, FRAMES))  # a prediction once the window is full
    for name, model in (("pose", Pose), ("action", Action), ("progress", Progress)):
        msgs = [m for m in first if m.topic.endswith("/" + name)]
        parsed = [model.model_validate_json(m.payload) for m in msgs]
        assert [p.seq for p in parsed] == expected, name  # continuous, in order, none lost
        assert all(not m.retain and m.content_type == "application/json" for m in msgs)
        assert all(m.expiry == 2 for m in msgs)
        assert all(0 <= p.latency_ms < 2000 for p in parsed)
    stamps = {
        name: {p["seq"]: tuple(json.dumps(p[k]) for k in STAMP_KEYS) for p in payloads(first, name)}
        for name in ("pose", "action", "progress")
    }
    assert stamps["pose"] == stamps["action"] == stamps["progress"]  # they join on seq
    assert len(frames["pose"][0].payload) > 100

    states = [Status.model_validate_json(m.payload) for m in first if m.topic.endswith("/status")]
    assert "online" in [s.state for s in states]
    assert states[-1].state == "offline"
    assert states[-1].reasons == ["stopped"]
    info = Info.model_validate_json(next(m for m in first if m.topic.endswith("/info")).payload)
    assert info.keypoints == list(KEYPOINTS)
    assert info.model["file"] == tiny_model_path.name
    health = Health.model_validate_json(
        [m for m in first if m.topic.endswith("/health")][-1].payload
    )
    assert health.published == len(expected)
    assert health.frames_in == {"left": FRAMES, "right": FRAMES}
    assert health.dropped == 0
    assert health.end_to_end.p50_ms is not None

    ready = [i for i, n in enumerate(notes) if n.startswith("READY=1")]
    assert len(ready) == 1  # systemd: ready once, when the source is up
    assert ready[0] < notes.index("STOPPING=1")
    assert "WATCHDOG=1" in notes
    assert any(n.startswith("STATUS=") and "broker connected" in n for n in notes)
    assert "STOPPING=1" in notes

    recording = tmp_path / "recorded.scotti"
    second = replay(
        mosquitto, session.path, tiny_model_path, tmp_path, "e2e-b", "--record", str(recording)
    )
    assert prediction_view(second) == prediction_view(first)  # same file, same predictions
    recorded = read_session(recording)  # --record kept every byte, closed cleanly
    assert recorded.header.source == "recorded"
    assert b"".join(p.data for p in recorded.packets) == session.data
    assert not recorded.truncated


def test_a_model_that_says_standing_publishes_null_progress_over_mqtt(
    mosquitto: Mosquitto, session: SyntheticSession, standing_model_path: Path, tmp_path: Path
) -> None:
    msgs = replay(mosquitto, session.path, standing_model_path, tmp_path, "e2e-standing")
    actions = [Action.model_validate_json(m.payload) for m in msgs if m.topic.endswith("/action")]
    progress = [
        Progress.model_validate_json(m.payload) for m in msgs if m.topic.endswith("/progress")
    ]
    # (A loaded machine may drop frames on the way: how many is not what this is about.)
    assert 0 < len(progress) <= FRAMES - WINDOW + 1
    assert [a.seq for a in actions] == [p.seq for p in progress]
    assert {a.action for a in actions} == {"standing"}
    assert all(a.schema_version == 3 and a.probabilities["standing"] > 0.99 for a in actions)
    # The tiny model is not calibrated: no unfamiliar score; a plausible map: nothing withheld.
    assert all(a.withheld is None and a.unfamiliar_score is None for a in actions)
    assert {(p.action, p.progress, p.repetition) for p in progress} == {("standing", None, -1)}
    raw = json.loads(next(m for m in msgs if m.topic.endswith("/progress")).payload)
    assert raw["progress"] is None  # JSON null on the wire, not NaN or a number
    info = Info.model_validate_json(next(m for m in msgs if m.topic.endswith("/info")).payload)
    assert info.actions[-1] == "standing"
    assert info.model["card"]["contract_version"] == 2


def test_an_empty_insole_pair_is_published_as_unloaded_with_no_action(
    mosquitto: Mosquitto, tiny_model_path: Path, tmp_path: Path
) -> None:
    """Nobody on the insoles: zeros from both feet, the whole session. Every prediction
    says unloaded, names no action, no progress and no count; status says why."""
    empty = np.zeros((FRAME_ROWS, FRAME_COLS), np.uint16)
    session = write_synthetic_session(
        tmp_path / "empty.scotti", frames=WINDOW + 20, counts_of=lambda *_: empty
    )
    msgs = replay(mosquitto, session.path, tiny_model_path, tmp_path, "e2e-empty")
    actions = [Action.model_validate_json(m.payload) for m in msgs if m.topic.endswith("/action")]
    progress = [
        Progress.model_validate_json(m.payload) for m in msgs if m.topic.endswith("/progress")
    ]
    poses = [Pose.model_validate_json(m.payload) for m in msgs if m.topic.endswith("/pose")]
    assert 0 < len(actions) <= 21
    assert [a.seq for a in actions] == [p.seq for p in progress] == [p.seq for p in poses]
    for a in actions:
        assert (a.action, a.confidence, a.withheld) == (None, 0.0, "unloaded")
        assert "unloaded" in a.flags
        assert a.unfamiliar_score is None  # the tiny model is not calibrated
    assert {(p.action, p.progress, p.repetition, p.withheld) for p in progress} == {
        (None, None, -1, "unloaded")
    }
    assert all("unloaded" in p.flags for p in poses)
    statuses = [Status.model_validate_json(m.payload) for m in msgs if m.topic.endswith("/status")]
    unloaded = [s for s in statuses if any(r.startswith("unloaded: ") for r in s.reasons)]
    assert unloaded
    assert all(s.state == "degraded" for s in unloaded)
    info = Info.model_validate_json(next(m for m in msgs if m.topic.endswith("/info")).payload)
    assert info.model["ood"]["calibrated"] is False
    assert info.model["input_checks"]["unloaded_force_n"] == 100.0


def test_live_board_subscriber_example_and_last_will_on_sigkill(
    mosquitto: Mosquitto,
    session: SyntheticSession,
    tiny_model_path: Path,
    tmp_path: Path,
    board_factory: Callable[..., BoardEmulator],
) -> None:
    board = board_factory(session, speed=2.0, loop=True)
    with collect(mosquitto, "scotti/live/#") as got:
        args = daemon_args(mosquitto, tiny_model_path, "live", "--port", str(board.link))
        daemon = start_daemon(args, tmp_path / "live.log")
        try:
            got.wait_for(
                lambda m: "online" in [s["state"] for s in payloads(m, "status")], 30, "online"
            )
            # The subscriber printed in docs/mqtt.md, run as a robot controller would.
            example = re.search(
                r"```python\n(import asyncio.*?)```", DOCS.joinpath("mqtt.md").read_text(), re.S
            )
            assert example is not None
            script = tmp_path / "subscriber.py"
            script.write_text(example.group(1))
            env = {
                **os.environ,
                "SCOTTI_BROKER": mosquitto.host,
                "SCOTTI_BROKER_PORT": str(mosquitto.port),
                "SCOTTI_DEVICE": "live",
                "SCOTTI_LIMIT": "5",
            }
            out = subprocess.run(
                [sys.executable, str(script)], env=env, capture_output=True, text=True, timeout=30
            )
            assert out.returncode == 0, out.stderr
            lines = out.stdout.splitlines()
            assert lines[0].startswith("status: online")
            assert len([ln for ln in lines if ln.startswith("seq ")]) == 5
            daemon.proc.send_signal(signal.SIGKILL)
            daemon.wait(10)
            got.wait_for(offline, 10, "the last will")
        finally:
            if daemon.proc.poll() is None:
                daemon.proc.kill()
    last = payloads(got.snapshot(), "status")[-1]
    assert last["state"] == "offline"
    assert last["reasons"] == ["connection lost (last will)"]
    with collect(mosquitto, "scotti/live/status") as late:  # and it stays: retained
        late.wait_for(lambda m: len(m) == 1 and m[0].retain and offline(m), 5)


def test_password_never_in_logs_or_info(
    session: SyntheticSession, tiny_model_path: Path, tmp_path: Path
) -> None:
    secret = "pw-7f3a9c-never-print-me"
    with Mosquitto(password=("robot", secret)) as broker:
        env = {"SCOTTI_MQTT_USERNAME": "robot", "SCOTTI_MQTT_PASSWORD": secret}
        msgs = replay(
            broker,
            session.path,
            tiny_model_path,
            tmp_path,
            "secret",
            SCOTTI_LOG_LEVEL="debug",
            **env,
        )
    assert payloads(msgs, "pose")  # it did log in with the password
    info = payloads(msgs, "info")[0]
    assert info["settings"]["mqtt"]["password_set"] is True
    log = (tmp_path / "secret.log").read_text()
    assert "DEBUG" in log
    assert secret not in log
    assert all(secret.encode() not in m.payload for m in msgs)
