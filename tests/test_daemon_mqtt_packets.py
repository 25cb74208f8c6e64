"""QoS 0 PUBLISH packets built by the daemon, written by ``Connection`` in one send.

The remaining length is checked against the spec's decoding algorithm (MQTT 5
section 1.5.5); whole packets against a real mosquitto, under MQTT 5 (with
content type and expiry) and 3.1.1, with payloads across the length's byte
boundaries, and in order with a retained publish that paho writes between
them.
"""

from __future__ import annotations

import asyncio
import logging
from typing import Literal

import pytest
from scotti.daemon.mqtt.connection import Connection
from scotti.daemon.mqtt.packets import (
    MAX_REMAINING,
    fixed_header,
    packet,
    publish_properties,
    topic_header,
)
from scotti.daemon.settings import MqttSettings
from scotti.daemon.tools.local_broker import Mosquitto

from tests.support.broker import collect


def decode_remaining(data: bytes) -> tuple[int, int]:
    """(value, bytes used) of the variable length integer at the start of ``data``."""
    value, multiplier = 0, 1
    for used, byte in enumerate(data, start=1):
        value += (byte & 0x7F) * multiplier
        if not byte & 0x80:
            return value, used
        multiplier *= 128
        assert used < 4, "more than four bytes"
    raise AssertionError("unterminated")


@pytest.mark.parametrize(
    ("remaining", "length_bytes"),
    [(0, 1), (127, 1), (128, 2), (16_383, 2), (16_384, 3), (2_097_151, 3), (2_097_152, 4),
     (MAX_REMAINING, 4)],
)  # fmt: skip
def test_remaining_length_is_the_specs_variable_length_integer(
    remaining: int, length_bytes: int
) -> None:
    header = fixed_header(remaining)
    assert header[0] == 0x30  # PUBLISH, QoS 0, not retained, not a duplicate
    assert decode_remaining(header[1:]) == (remaining, length_bytes)
    assert len(header) == 1 + length_bytes


def test_a_packet_too_long_for_mqtt_is_refused() -> None:
    with pytest.raises(ValueError, match="at most 268435455"):
        fixed_header(MAX_REMAINING + 1)


def test_packet_is_header_topic_and_payload() -> None:
    data = packet(topic_header("a/b", None), b"xyz")
    assert data == b"\x30\x08\x00\x03a/bxyz"


SIZES = (1, 100, 200, 16_000, 16_400, 2_100_000)


async def _send(broker: Mosquitto, protocol: Literal["5", "3.1.1"]) -> None:
    settings = MqttSettings(broker=broker.url, device_id="pk", protocol=protocol)
    conn = Connection(
        settings, ("scotti/pk/status", b"gone", None), lambda _m: None, logging.getLogger("t")
    )
    await conn.open()
    props = publish_properties("json", 7) if protocol == "5" else None
    header = topic_header("scotti/pk/pose", props)
    for i, size in enumerate(SIZES[:3]):
        conn.queue_frame(packet(header, bytes([i]) * size))
    conn.write()  # the frames queued so far, then a retained publish paho queues after them
    reason = await asyncio.wait_for(conn.publish("scotti/pk/status", b"ok", 1, True, None), 10)
    assert reason is None or not reason.is_failure
    for i, size in enumerate(SIZES[3:], start=3):
        conn.queue_frame(packet(header, bytes([i]) * size))
    conn.write()
    await asyncio.wait_for(conn.frames_written(), 10)
    assert conn.frames_waiting == 0
    await conn.close()


@pytest.mark.mosquitto
@pytest.mark.parametrize("protocol", ["5", "3.1.1"])
def test_frames_arrive_whole_with_their_properties_and_in_order(
    mosquitto: Mosquitto, protocol: Literal["5", "3.1.1"]
) -> None:
    with collect(mosquitto, "scotti/pk/#") as got:
        asyncio.run(_send(mosquitto, protocol))
        got.wait_for(lambda m: len(m) == len(SIZES) + 1, 10, "every message")
    msgs = got.snapshot()
    assert [m.topic.rsplit("/", 1)[1] for m in msgs] == ["pose"] * 3 + ["status"] + ["pose"] * 3
    frames = [m for m in msgs if m.topic.endswith("pose")]
    assert [m.payload for m in frames] == [bytes([i]) * n for i, n in enumerate(SIZES)]
    assert not any(m.retain for m in frames)
    if protocol == "5":
        assert all(m.content_type == "application/json" and m.expiry == 7 for m in frames)
    else:
        assert all(m.content_type is None and m.expiry is None for m in frames)
