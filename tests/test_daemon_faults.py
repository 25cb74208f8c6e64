"""Faults the daemon must survive or refuse cleanly, with real parts: pty board, mosquitto."""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import onnx
import pytest
from scotti.daemon.input.board_emulator import BoardEmulator
from scotti.daemon.mqtt.schemas import Health
from scotti.daemon.tools.local_broker import Mosquitto
from scotti.firmware_protocol.packets import Foot
from scotti.models.contract import META_CONTRACT_VERSION, WINDOW

from tests.support.broker import Received, collect, payloads, start_daemon
from tests.support.fixtures_models import TINY_V1_STEP
from tests.support.sessions import SyntheticSession, write_synthetic_session

DAEMON = str(Path(sys.executable).with_name("scotti-daemon"))


def states(msgs: list[Received]) -> list[tuple[str, list[str]]]:
    return [(s["state"], s["reasons"]) for s in payloads(msgs, "status")]


def last_state(msgs: list[Received]) -> str | None:
    st = states(msgs)
    return st[-1][0] if st else None


def poses_after(msgs: list[Received], t: float) -> int:
    return len([m for m in msgs if m.topic.endswith("/pose") and m.at > t])


def live_args(broker: Mosquitto, model: Path, device: str, link: Path) -> list[str]:
    args = ["--port", str(link), "--model", str(model), "--broker", broker.url]
    return [*args, "--device-id", device]


@pytest.fixture
def looping(tmp_path: Path, board_factory: Callable[..., BoardEmulator]) -> BoardEmulator:
    # Long enough that the loop's restart (seqs jump back: the window warms up again)
    # does not fall inside a test.
    session = write_synthetic_session(tmp_path / "loop.scotti", frames=480)
    return board_factory(session, speed=2.0, loop=True)


@pytest.mark.mosquitto
@pytest.mark.slow
def test_unplug_and_replug_the_board(
    mosquitto: Mosquitto, looping: BoardEmulator, tiny_model_path: Path, tmp_path: Path
) -> None:
    with collect(mosquitto, "scotti/plug/#") as got:
        daemon = start_daemon(
            live_args(mosquitto, tiny_model_path, "plug", looping.link), tmp_path / "plug.log"
        )
        try:
            got.wait_for(lambda m: last_state(m) == "online", 30, "online")
            before = len(states(got.snapshot()))  # "not connected yet" may be among them
            unplugged_at = time.monotonic()
            looping.unplug()
            got.wait_for(
                lambda m: any(
                    "receiver disconnected" in " ".join(r) for _, r in states(m)[before:]
                ),
                10,
                "degraded: receiver disconnected",
            )
            assert last_state(got.snapshot()) == "degraded"
            time.sleep(0.5)  # any pose from before the cut would have come by now
            cut = next(
                m.at
                for m in got.snapshot()
                if m.topic.endswith("/status")
                and b"receiver disconnected" in m.payload
                and m.at > unplugged_at
            )
            assert poses_after(got.snapshot(), cut) == 0  # none follows the disconnect
            looping.replug()
            replugged = time.monotonic()
            got.wait_for(lambda m: last_state(m) == "online", 30, "online again")
            got.wait_for(lambda m: poses_after(m, replugged) >= 5, 10, "predictions resume")
        finally:
            assert daemon.stop() == 0, daemon.log
    seqs = [p["seq"] for p in payloads(got.snapshot(), "pose")]
    assert seqs == sorted(seqs)  # seq keeps counting across the unplug
    assert len(set(seqs)) == len(seqs)
    # Back from the replug, the window is empty: warming up first, never a stale "online".
    st = states(got.snapshot())
    cut = max(i for i, (_, r) in enumerate(st) if "receiver disconnected" in " ".join(r))
    after = st[cut + 1 :]
    online = next(i for i, (s, _) in enumerate(after) if s == "online")
    assert online > 0
    assert all(s == "degraded" and "warming up" in r for s, r in after[:online]), after


@pytest.mark.mosquitto
@pytest.mark.slow
def test_broker_restart_mid_stream(
    mosquitto: Mosquitto, looping: BoardEmulator, tiny_model_path: Path, tmp_path: Path
) -> None:
    env = {"SCOTTI_MQTT_HEALTH_INTERVAL_S": "0.5", "SCOTTI_MQTT_RECONNECT_MAX_S": "0.5"}
    args = live_args(mosquitto, tiny_model_path, "outage", looping.link)
    daemon = start_daemon(args, tmp_path / "outage.log", env=env)
    try:
        with collect(mosquitto, "scotti/outage/#") as got:
            got.wait_for(lambda m: last_state(m) == "online", 30, "online")
        mosquitto.stop()  # the broker dies (no persistence: its retained state is gone)
        time.sleep(2.0)  # the daemon keeps reading and predicting, unsent
        mosquitto.start()
        with collect(mosquitto, "scotti/outage/#") as got:
            got.wait_for(lambda m: len(payloads(m, "pose")) >= 5, 20, "predictions again")
            republished = {m.topic.rsplit("/", 1)[1] for m in got.snapshot()}
            assert republished >= {"status", "info"}
            assert last_state(got.snapshot()) == "online"

            def recovered(m: list[Received]) -> bool:
                h = payloads(m, "health")
                return bool(h) and h[-1]["broker_reconnects"] >= 1 and h[-1]["dropped"] > 0

            got.wait_for(recovered, 10, "health counting the outage")
            health = Health.model_validate(payloads(got.snapshot(), "health")[-1])
        assert health.dropped > 0
        with collect(mosquitto, "scotti/outage/#") as late:  # held by the new broker
            late.wait_for(
                lambda m: {x.topic.rsplit("/", 1)[1] for x in m if x.retain} >= {"status", "info"},
                5,
                "retained status and info",
            )
        assert health.predictions > health.published  # predicted all along, sent what it could
        assert daemon.proc.poll() is None
    finally:
        assert daemon.stop() == 0, daemon.log


def replay_collect(
    broker: Mosquitto, session: SyntheticSession, model: Path, tmp_path: Path, device: str
) -> list[Received]:
    with collect(broker, f"scotti/{device}/#") as got:
        args = ["--replay", str(session.path), "--speed", "8", "--model", str(model)]
        args += ["--broker", broker.url, "--device-id", device]
        env = {"SCOTTI_MQTT_HEALTH_INTERVAL_S": "0.3"}
        daemon = start_daemon(args, tmp_path / f"{device}.log", env=env)
        assert daemon.wait(60) == 0, daemon.log
        got.wait_for(lambda m: last_state(m) == "offline", 5, "offline")
    return got.snapshot()


@pytest.mark.mosquitto
@pytest.mark.slow
def test_one_foot_silent_degrades_with_a_reason(
    mosquitto: Mosquitto, tiny_model_path: Path, tmp_path: Path
) -> None:
    session = write_synthetic_session(tmp_path / "left.scotti", frames=96, feet=(Foot.LEFT,))
    msgs = replay_collect(mosquitto, session, tiny_model_path, tmp_path, "onefoot")
    reasons = [r for state, rs in states(msgs) if state == "degraded" for r in rs]
    assert "right insole silent" in reasons
    poses = payloads(msgs, "pose")
    assert poses  # still predicting, flagged
    assert any("right_filled" in p["flags"] or "right_held" in p["flags"] for p in poses)


@pytest.mark.mosquitto
@pytest.mark.slow
def test_garbage_on_the_line_is_counted_and_predictions_continue(
    mosquitto: Mosquitto, tiny_model_path: Path, tmp_path: Path
) -> None:
    frames = 80
    session = write_synthetic_session(tmp_path / "noisy.scotti", frames=frames, garbage_every=3)
    msgs = replay_collect(mosquitto, session, tiny_model_path, tmp_path, "noisy")
    seqs = [p["seq"] for p in payloads(msgs, "pose")]
    assert seqs == list(range(WINDOW - 1, frames))  # not one frame lost to the noise
    health = Health.model_validate(payloads(msgs, "health")[-1])
    assert health.bad_packets > 0


def run_daemon(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    import os

    clean = {k: v for k, v in os.environ.items() if not k.startswith("SCOTTI_")}
    return subprocess.run(
        [DAEMON, *args],
        capture_output=True,
        text=True,
        timeout=60,
        env={**clean, **(env or {})},
    )


def assert_one_line(out: subprocess.CompletedProcess[str], starts: str) -> None:
    assert out.returncode == 78, out.stderr
    assert "Traceback" not in out.stderr
    lines = out.stderr.splitlines()
    assert len(lines) == 1, out.stderr
    assert lines[0].startswith(starts), lines[0]


@pytest.mark.parametrize(
    ("args", "env", "starts"),
    [
        (
            ["--port", "/dev/x", "--broker", "mqtt://h:70000"],
            {},
            "scotti-daemon: config error: "
            "mqtt.broker: broker 'mqtt://h:70000': port must be 1..65535",
        ),
        (
            ["--port", "/dev/x", "--device-id", "a+b"],
            {},
            "scotti-daemon: config error: mqtt.device_id",
        ),
        (
            ["--port", "/dev/x"],
            {"SCOTTI_MODEL_THREADS": "0"},
            "scotti-daemon: config error: "
            "model.threads: Input should be greater than or equal to 1",
        ),
        (
            ["--speed", "fast", "--simulate", "demo"],
            {},
            "scotti-daemon: config error: source.speed",
        ),
        ([], {}, "scotti-daemon: config error: source: no source"),
        (
            ["--port", "/dev/x", "--broker", "mqtt://h:0"],
            {},
            "scotti-daemon: config error: mqtt.broker: broker 'mqtt://h:0': port must be 1..65535",
        ),
        (
            ["--port", "/dev/x", "--broker", "garbage"],
            {},
            "scotti-daemon: config error: mqtt.broker: broker 'garbage': give a URL",
        ),
        (
            ["--port", "/dev/x", "--broker", "mqtt://:1883"],
            {},
            "scotti-daemon: config error: mqtt.broker: broker 'mqtt://:1883': no host",
        ),
        (
            ["--port", "/dev/x", "--device-id", "d" * 10_000],
            {},
            "scotti-daemon: config error: mqtt.device_id: device id 'dddd",
        ),
        (
            ["--port", "/dev/x", "--config", "/nonexistent.toml"],
            {},
            "scotti-daemon: config error: cannot read config file /nonexistent.toml",
        ),
    ],
)
def test_config_error_is_one_line_exit_78(
    args: list[str], env: dict[str, str], starts: str
) -> None:
    assert_one_line(run_daemon(*args, env=env), starts)


def test_unknown_scene_is_one_line_exit_78(tmp_path: Path) -> None:
    record = tmp_path / "never.scotti"
    out = run_daemon("--simulate", "no-such-scene", "--record", str(record))
    assert_one_line(out, "scotti-daemon: error: scene 'no-such-scene': no such file")
    assert not record.exists()  # refused before anything was started or created


def test_model_that_does_not_fit_the_contract(tiny_model_path: Path, tmp_path: Path) -> None:
    model = onnx.load(str(tiny_model_path))
    for prop in model.metadata_props:
        if prop.key == META_CONTRACT_VERSION:
            prop.value = "99"
    wrong = tmp_path / "wrong-contract.onnx"
    onnx.save(model, str(wrong))
    out = run_daemon("--port", "/dev/x", "--model", str(wrong))
    assert_one_line(out, "scotti-daemon: model error: wrong-contract.onnx")
    out = run_daemon("--port", "/dev/x", "--model", str(TINY_V1_STEP))
    assert_one_line(
        out, "scotti-daemon: model error: scotti-tiny.onnx: model has contract version 1,"
    )
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(b"not a model")
    assert_one_line(
        run_daemon("--port", "/dev/x", "--model", str(junk)), "scotti-daemon: model error"
    )
