"""Beyond one host (docs/deploy.md): two daemons, each on its own mosquitto, one of
the brokers bridged into the other; a subscriber on the central broker sees both
devices' predictions, status and health under their own names."""

from __future__ import annotations

import time
from pathlib import Path

import paho.mqtt.publish
import pytest
from scotti.daemon.mqtt.schemas import Health, Status
from scotti.daemon.tools.local_broker import Mosquitto, bridge_conf
from scotti.models.contract import WINDOW

from tests.support.broker import Collector, Received, collect, payloads, start_daemon
from tests.support.sessions import write_synthetic_session

pytestmark = [pytest.mark.mosquitto, pytest.mark.slow]

FRAMES = 100


def wait_for_bridge(edge: Mosquitto, central: Collector) -> None:
    """Publish probes on the edge broker until one arrives on the central one."""
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        paho.mqtt.publish.single("scotti/probe", b"1", hostname=edge.host, port=edge.port)
        if central.snapshot("probe"):
            return
        time.sleep(0.1)
    msg = f"bridge never came up: {edge.log_tail()}"
    raise AssertionError(msg)


def test_two_daemons_through_bridged_brokers_reach_one_subscriber(
    tiny_model_path: Path, tmp_path: Path
) -> None:
    session = write_synthetic_session(tmp_path / "s.scotti", frames=FRAMES)
    central = Mosquitto()
    edge = Mosquitto(extra_conf=bridge_conf("site-a", f"{central.host}:{central.port}"))
    with central, edge, collect(central, "scotti/#") as got:
        wait_for_bridge(edge, got)
        daemons = [
            start_daemon(
                ["--replay", str(session.path), "--speed", "max", "--model", str(tiny_model_path),
                 "--broker", broker.url, "--device-id", device],
                tmp_path / f"{device}.log",
            )
            for broker, device in ((edge, "site-a-pair1"), (central, "site-b-pair1"))
        ]  # fmt: skip
        for daemon in daemons:
            assert daemon.wait(60) == 0, daemon.log

        def both_offline(msgs: list[Received]) -> bool:
            return all(
                any(
                    Status.model_validate_json(m.payload).state == "offline"
                    for m in msgs
                    if m.topic == f"scotti/{device}/status"
                )
                for device in ("site-a-pair1", "site-b-pair1")
            )

        got.wait_for(both_offline, 10, "both devices offline on the central broker")
    msgs = got.snapshot()
    expected = list(range(WINDOW - 1, FRAMES))
    for device in ("site-a-pair1", "site-b-pair1"):
        mine = [m for m in msgs if m.topic.startswith(f"scotti/{device}/")]
        assert [p["seq"] for p in payloads(mine, "pose")] == expected, device
        health = [
            Health.model_validate_json(m.payload) for m in mine if m.topic.endswith("/health")
        ]
        assert health
        assert health[-1].published == len(expected)
    bridged = [m for m in msgs if m.topic == "scotti/site-a-pair1/pose"]
    assert bridged[0].content_type == "application/json"  # v5 properties cross the bridge
    assert bridged[0].expiry is not None
    assert bridged[0].expiry <= 2
