"""Publisher against a real mosquitto: retained state, v5 properties, queue, reconnects."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Awaitable, Callable

import msgpack
import pytest
from scotti.daemon.frames.pipeline import Prediction
from scotti.daemon.mqtt.latency_slot import LatencySlot
from scotti.daemon.mqtt.publisher import Publisher
from scotti.daemon.mqtt.schemas import Info, Progress, Status
from scotti.daemon.settings import MqttSettings
from scotti.daemon.tools.local_broker import Mosquitto

from tests.support.broker import Received, collect
from tests.support.publishing import batch, info, status

pytestmark = pytest.mark.mosquitto


def settings(broker: Mosquitto, **kw: object) -> MqttSettings:
    return MqttSettings(
        broker=broker.url,
        device_id="dev1",
        reconnect_max_s=0.5,
        **kw,  # type: ignore[arg-type]
    )


def running(
    make: Callable[[], Publisher],
    body: Callable[[Publisher], Awaitable[None]],
    timeout: float = 20,
) -> Publisher:
    """Run a publisher (made inside the loop, as aiomqtt requires) while ``body`` runs."""
    return asyncio.run(_running(make, body, timeout))


async def _running(
    make: Callable[[], Publisher], body: Callable[[Publisher], Awaitable[None]], within: float
) -> Publisher:
    pub = make()
    stop = asyncio.Event()
    task = asyncio.create_task(pub.run(stop))
    try:
        await asyncio.wait_for(body(pub), within)
    finally:
        stop.set()
        await asyncio.wait_for(task, 10)
    return pub


async def until(cond: Callable[[], bool], within: float = 10) -> None:
    deadline = time.monotonic() + within
    while not cond():
        assert time.monotonic() < deadline, "condition not met in time"
        await asyncio.sleep(0.02)


def seqs(msgs: list[Received]) -> list[int]:
    return [Progress.model_validate_json(m.payload).seq for m in msgs]


def test_publishes_retained_state_and_frames_with_v5_properties(mosquitto: Mosquitto) -> None:
    with collect(mosquitto, "scotti/dev1/#") as got:

        async def body(pub: Publisher) -> None:
            pub.set_status(status("online"))
            await until(lambda: pub.state == "connected")
            for seq in range(5):
                pub.submit(batch(seq))
            await until(lambda: pub.stats.published == 5)

        running(lambda: Publisher(settings(mosquitto), info(), will=status("offline")), body)
        got.wait_for(lambda m: len([x for x in m if x.topic.endswith("progress")]) == 5, 5)
    frames = got.snapshot("progress")
    assert seqs(frames) == [0, 1, 2, 3, 4]
    assert all(m.content_type == "application/json" and m.expiry == 2 for m in frames)
    assert not any(m.retain for m in frames)
    assert 0 <= Progress.model_validate_json(frames[0].payload).latency_ms < 1000
    (st,) = got.snapshot("status")
    assert Status.model_validate_json(st.payload).state == "online"
    assert Info.model_validate_json(got.snapshot("info")[0].payload).device_id == "dev1"


def test_retained_state_is_there_for_a_late_subscriber(mosquitto: Mosquitto) -> None:
    async def body(pub: Publisher) -> None:
        pub.set_status(status("degraded"))
        await until(lambda: pub.state == "connected")
        await asyncio.sleep(0.3)

    mqtt = settings(mosquitto, format="msgpack")
    running(lambda: Publisher(mqtt, info(), will=status("offline")), body)
    with collect(mosquitto, "scotti/dev1/#") as got:
        got.wait_for(lambda m: len(m) >= 2, 5, "retained status and info")
    st = got.snapshot("status")[0]
    assert st.retain
    assert st.content_type == "application/msgpack"
    assert msgpack.unpackb(st.payload)["state"] == "degraded"


def test_queue_drops_the_oldest_and_counts() -> None:
    async def fill() -> Publisher:  # not run: nothing leaves the queue
        mqtt = MqttSettings(broker="mqtt://127.0.0.1:1", device_id="d", queue_size=4)
        pub = Publisher(mqtt, info(), will=status("offline"))
        for seq in range(10):
            pub.submit(batch(seq))
        return pub

    pub = asyncio.run(fill())
    assert pub.queue_depth == 4
    assert pub.stats.dropped_full == 6
    assert [b.seq for b in pub._queue] == [6, 7, 8, 9]


def test_starts_with_broker_down_and_recovers_after_restart(mosquitto: Mosquitto) -> None:
    mosquitto.stop()

    async def body(pub: Publisher) -> None:
        pub.set_status(status("online"))
        for seq in range(20):  # nobody to send to: queued, oldest dropped
            pub.submit(batch(seq))
            await asyncio.sleep(0.01)
        await asyncio.sleep(0.5)
        assert pub.state == "disconnected"
        assert pub.stats.dropped_full == 12
        mosquitto.start()
        await until(lambda: pub.state == "connected")
        await until(lambda: pub.stats.published == 8)
        with_restart = pub.stats.connects
        mosquitto.stop()  # lose the broker mid-stream
        for seq in range(20, 30):
            pub.submit(batch(seq))
            await asyncio.sleep(0.02)
        await until(lambda: pub.state == "disconnected")
        mosquitto.start()
        await until(lambda: pub.stats.connects == with_restart + 1)
        await until(lambda: pub.queue_depth == 0)

    mqtt = settings(mosquitto, queue_size=8)
    pub = running(lambda: Publisher(mqtt, info(), will=status("offline")), body, timeout=40)
    assert pub.stats.reconnects >= 1
    assert pub.stats.published + pub.stats.dropped == 30
    # After the last reconnect the retained state was published again.
    with collect(mosquitto, "scotti/dev1/#") as got:
        got.wait_for(lambda m: {x.topic.rsplit("/", 1)[1] for x in m} >= {"status", "info"}, 5)


def test_latency_ms_counts_the_encoding_up_to_the_hand_off(mosquitto: Mosquitto) -> None:
    # A prediction whose payloads take 200 ms to build: latency_ms is taken as the
    # bytes are handed to the client, so those 200 ms are in it.
    slow_ms = 200

    class SlowPublisher(Publisher):
        def encode_frame(self, prediction: Prediction) -> list[tuple[bytes, LatencySlot]]:
            time.sleep(slow_ms / 1e3)
            return super().encode_frame(prediction)

    with collect(mosquitto, "scotti/dev1/progress") as got:

        async def body(pub: Publisher) -> None:
            await until(lambda: pub.state == "connected")
            pub.submit(batch(1))
            await until(lambda: pub.stats.published == 1)

        pub = running(
            lambda: SlowPublisher(settings(mosquitto), info(), will=status("offline")), body
        )
        got.wait_for(lambda m: len(m) == 1, 5)
    sent = Progress.model_validate_json(got.snapshot()[0].payload).latency_ms
    assert sent >= slow_ms
    # health's end_to_end is taken after the publish returned: never earlier.
    assert pub.stats.latency_ms.summary()["max"] >= sent


def test_a_full_queue_is_logged_once_not_per_drop(caplog: pytest.LogCaptureFixture) -> None:
    async def fill() -> Publisher:  # not run: nothing leaves the queue
        mqtt = MqttSettings(broker="mqtt://127.0.0.1:1", device_id="d", queue_size=4)
        pub = Publisher(mqtt, info(), will=status("offline"))
        for seq in range(40):
            pub.submit(batch(seq))
        return pub

    with caplog.at_level("WARNING", logger="scotti.daemon.mqtt.publisher"):
        pub = asyncio.run(fill())
    assert pub.stats.dropped_full == 36
    lines = [r.getMessage() for r in caplog.records if "queue full" in r.getMessage()]
    assert len(lines) == 1, lines
    assert "dropped the oldest prediction" in lines[0]
