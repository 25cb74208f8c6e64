"""LatencySlot: a payload encoded once, its latency_ms written in as it leaves."""

from __future__ import annotations

from typing import Literal

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scotti.daemon.mqtt.latency_slot import LatencySlot
from scotti.daemon.mqtt.schemas import DeviceSeq, Pose, Progress, Status, decode, encode

FORMATS: list[Literal["json", "msgpack"]] = ["json", "msgpack"]


def progress(latency_ms: float = 0.0) -> Progress:
    return Progress(
        seq=7,
        device_seq=DeviceSeq(left=65535, right=0),
        device_time_us=123_456,
        host_wall_ns=1_700_000_000_000_000_000,
        host_mono_ns=99,
        predicted_for_mono_ns=100,
        latency_ms=latency_ms,
        flags=["left_held"],
        action="squat",
        progress=0.25,
        repetition=3,
    )


@pytest.mark.parametrize("fmt", FORMATS)
@settings(max_examples=60, deadline=None)
@given(st.floats(0.0, 1e7, allow_nan=False))
def test_filled_payload_decodes_with_that_latency_and_nothing_else_changed(
    fmt: Literal["json", "msgpack"], latency_ms: float
) -> None:
    slot = LatencySlot.encode(progress(), fmt)
    got = decode(Progress, slot.fill(latency_ms), fmt)
    assert got == progress(round(latency_ms, 3))


@pytest.mark.parametrize("fmt", FORMATS)
def test_filled_payload_is_byte_for_byte_the_payload_encoded_with_that_latency(
    fmt: Literal["json", "msgpack"],
) -> None:
    slot = LatencySlot.encode(progress(), fmt)
    assert slot.fill(12.5) == encode(progress(12.5), fmt)
    pose = Pose(**progress().model_dump(include=set(Pose.model_fields) - {"schema_version"}),
                keypoints=[[0.0, 0.1, 0.2]] * 19)  # fmt: skip
    assert decode(Pose, LatencySlot.encode(pose, fmt).fill(3.25), fmt).latency_ms == 3.25


@pytest.mark.parametrize("fmt", FORMATS)
def test_a_payload_without_latency_is_sent_as_encoded(fmt: Literal["json", "msgpack"]) -> None:
    status = Status(
        state="online", reasons=[], source="connected", feet={}, warming=(0, 40), host_wall_ns=1
    )
    assert LatencySlot.encode(status, fmt).fill(5.0) == encode(status, fmt)
