"""A replay at --speed max publishes every prediction: it waits for the publisher
(as it waits for inference) instead of dropping; a subscriber on a real mosquitto
counts them."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from scotti.daemon.mqtt.schemas import Health, Pose
from scotti.daemon.tools.local_broker import Mosquitto
from scotti.models.contract import WINDOW

from tests.support.broker import collect, payloads, start_daemon
from tests.support.sessions import write_synthetic_session

pytestmark = [pytest.mark.mosquitto, pytest.mark.slow]

FRAMES = 400  # 25 s of insole time, replayed in a few seconds


def test_replay_at_max_speed_publishes_every_prediction(
    mosquitto: Mosquitto, tiny_model_path: Path, tmp_path: Path
) -> None:
    session = write_synthetic_session(tmp_path / "long.scotti", frames=FRAMES)
    device = "lossless"
    with collect(mosquitto, f"scotti/{device}/#") as got:
        args = ["--replay", str(session.path), "--speed", "max", "--model", str(tiny_model_path)]
        args += ["--broker", mosquitto.url, "--device-id", device]
        daemon = start_daemon(args, tmp_path / "daemon.log")
        assert daemon.wait(60) == 0, daemon.log
        got.wait_for(
            lambda m: any(s["state"] == "offline" for s in payloads(m, "status")),
            10,
            "status offline",
        )
    msgs = got.snapshot()
    expected = list(range(WINDOW - 1, FRAMES))  # one prediction per frame once the window is full
    for name in ("pose", "action", "progress"):
        assert [p["seq"] for p in payloads(msgs, name)] == expected, name
    Pose.model_validate_json(next(m for m in msgs if m.topic.endswith("/pose")).payload)
    health = Health.model_validate_json(
        [m for m in msgs if m.topic.endswith("/health")][-1].payload
    )
    assert health.predictions == health.published == len(expected)
    assert health.dropped == 0
    assert health.dropped_frames == 0
    # The replay says how fast it went.
    rate = re.search(r"(\d+) paired frames in [\d.]+ s \((\d+) frames/s\)", daemon.log)
    assert rate is not None, daemon.log
    assert int(rate.group(1)) == FRAMES
    assert int(rate.group(2)) > 0
