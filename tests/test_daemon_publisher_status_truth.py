"""The daemon's retained status cannot be forged for long, and refusals are counted.

Against a real mosquitto: another client (``mosquitto_pub``) publishes a
different retained status on the daemon's topic and the publisher puts the
truth back; a broker whose ACL denies the status topic answers the QoS 1
publish with reason code 0x87 (MQTT v5), which health reports as refused
instead of the status being taken for published.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import shutil
import subprocess
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Literal

import pytest
from scotti.daemon.mqtt import messages
from scotti.daemon.mqtt.publisher import Publisher
from scotti.daemon.mqtt.schemas import Status, encode
from scotti.daemon.service.counters import Counters
from scotti.daemon.settings import MqttSettings
from scotti.daemon.tools.local_broker import Mosquitto

from tests.support.broker import collect
from tests.support.publishing import info, status
from tests.test_daemon_publisher import running, until

pytestmark = pytest.mark.mosquitto

TOPIC = "scotti/dev1/status"


def forge(broker: Mosquitto, payload: bytes) -> None:
    """Another client's retained status, as anyone on the network could send it."""
    exe = shutil.which("mosquitto_pub")
    if exe is None:
        pytest.skip("mosquitto_pub not installed")
    args = ["-h", broker.host, "-p", str(broker.port), "-t", TOPIC, "-q", "1", "-r"]
    subprocess.run([exe, *args, "-s"], input=payload, check=True, timeout=10)


def retained_status(broker: Mosquitto) -> bytes:
    with collect(broker, TOPIC) as got:
        (msg,) = got.wait_for(lambda m: len(m) >= 1, 5, "the retained status")
    assert msg.retain
    return msg.payload


@pytest.mark.parametrize("protocol", ["5", "3.1.1"])
@pytest.mark.parametrize("forged", ["online", "offline"])
def test_a_forged_retained_status_is_replaced_with_the_truth(
    mosquitto: Mosquitto,
    protocol: Literal["5", "3.1.1"],
    forged: Literal["online", "offline"],
    caplog: pytest.LogCaptureFixture,
) -> None:
    truth = status("degraded")
    lie = Status(
        state=forged,
        reasons=["forged"],
        source="connected",
        feet={},
        warming=(40, 40),
        host_wall_ns=2,
    )
    mqtt = MqttSettings(broker=mosquitto.url, device_id="dev1", protocol=protocol, ack_timeout_s=1)

    async def body(pub: Publisher) -> None:
        # Status changes of its own are not taken for someone else's (under 3.1.1
        # they come back from the broker).
        for state in ("online", "degraded", "online"):
            pub.set_status(status(state))  # type: ignore[arg-type]
            await asyncio.sleep(0.1)
        pub.set_status(truth)
        await until(lambda: pub.state == "connected")
        await asyncio.sleep(1.2)  # past the once-a-second limit on restoring
        assert pub.stats.status_restored == 0
        await asyncio.to_thread(forge, mosquitto, encode(lie, "json"))
        await until(lambda: pub.stats.status_restored == 1)
        await asyncio.sleep(0.3)

    with caplog.at_level("WARNING", logger="scotti.daemon.mqtt.publisher"):
        pub = running(lambda: Publisher(mqtt, info(), will=status("offline")), body)
    assert pub.stats.status_restored == 1
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 1, lines  # the replacement, once; the watch worked (no "cannot read")
    assert "changed by another client" in lines[0]
    # Restored on the broker (the publisher stopped without a final status here).
    assert Status.model_validate_json(retained_status(mosquitto)) == truth


def test_a_status_war_is_fought_at_most_once_a_second(mosquitto: Mosquitto) -> None:
    """Two daemons on one device id (or a persistent forger): bounded, not a flood."""
    mqtt = MqttSettings(broker=mosquitto.url, device_id="dev1")
    lie = encode(status("offline"), "json")

    async def body(pub: Publisher) -> None:
        pub.set_status(status("online"))
        await until(lambda: pub.state == "connected")
        for _ in range(10):  # ten forgeries in about a second
            await asyncio.to_thread(forge, mosquitto, lie)
        await asyncio.sleep(1.5)

    pub = running(lambda: Publisher(mqtt, info(), will=status("offline")), body)
    assert 1 <= pub.stats.status_restored <= 3
    assert Status.model_validate_json(retained_status(mosquitto)).state == "online"


@contextlib.contextmanager
def broker_with_acl(acl_text: str) -> Iterator[Mosquitto]:
    """mosquitto with ``acl_text`` as its ACL file (for anonymous clients)."""
    # Not under pytest's tmp_path: mosquitto started as root reads it as user
    # "mosquitto", who cannot enter /tmp/pytest-of-root.
    folder = Path(tempfile.mkdtemp(prefix="scotti-acl-"))
    folder.chmod(0o755)
    acl = folder / "acl"
    acl.write_text(acl_text)
    acl.chmod(0o644)
    broker = Mosquitto(extra_conf=[f"acl_file {acl}"])
    try:
        broker.start()
        yield broker
    finally:
        broker.close()
        shutil.rmtree(folder, ignore_errors=True)


@pytest.fixture
def denying_broker() -> Iterator[Mosquitto]:
    """Anonymous clients may do anything but publish our status."""
    with broker_with_acl(f"topic readwrite #\ntopic deny {TOPIC}\n") as broker:
        yield broker


def test_a_refused_status_is_counted_and_reported_not_taken_for_published(
    denying_broker: Mosquitto, caplog: pytest.LogCaptureFixture
) -> None:
    said: list[Status] = []
    mqtt = MqttSettings(broker=denying_broker.url, device_id="dev1")

    async def body(pub: Publisher) -> None:
        pub.on_status_published = said.append
        pub.set_status(status("online"))
        await until(lambda: pub.state == "connected")
        await until(lambda: pub.stats.refused >= 1)
        pub.set_health(messages.health(Counters().snapshot(), pub, 1.0))
        await asyncio.sleep(0.5)

    with (
        collect(denying_broker, "scotti/dev1/health") as got,
        caplog.at_level("WARNING", logger="scotti.daemon.mqtt.publisher"),
    ):
        pub = running(lambda: Publisher(mqtt, info(), will=status("offline")), body)
        got.wait_for(lambda m: len(m) >= 1, 5, "health")
    assert said == []  # never said in the log as published
    assert pub.stats.refused >= 1
    assert pub.stats.last_refused == f"{TOPIC}: Not authorized (0x87)"
    publish = json.loads(got.snapshot()[-1].payload)["pipeline"]["publish"]
    assert publish["refused"] >= 1
    assert publish["last_refused"] == pub.stats.last_refused
    warnings = [r.getMessage() for r in caplog.records if "refused a publish" in r.getMessage()]
    assert len(warnings) == 1, warnings
    assert "Not authorized" in warnings[0]


def test_a_status_it_may_not_read_is_published_unwatched(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """An ACL that lets the daemon write its topics but not read them (docs/mqtt.md's
    before the status was watched): one WARNING, and publishing goes on."""
    with broker_with_acl("topic write #\n") as broker:
        mqtt = MqttSettings(broker=broker.url, device_id="dev1", ack_timeout_s=0.5)

        async def body(pub: Publisher) -> None:
            pub.set_status(status("online"))
            await until(lambda: pub.state == "connected")
            await asyncio.sleep(1.5)

        with caplog.at_level("WARNING", logger="scotti.daemon.mqtt.publisher"):
            pub = running(lambda: Publisher(mqtt, info(), will=status("offline")), body)
    assert pub.stats.connects == 1
    assert pub.state == "stopped"
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 1, lines
    assert "cannot read scotti/dev1/status" in lines[0]
