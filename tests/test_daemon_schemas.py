"""Payload schemas: both encodings round-trip, bad payloads fail, the docs match the models."""

from __future__ import annotations

import base64
import json
import re
from pathlib import Path
from typing import Any, get_args

import msgpack
import pytest
from pydantic import ValidationError
from scotti.daemon.mqtt import schemas
from scotti.daemon.mqtt.schemas import (
    Action,
    DeviceSeq,
    Pose,
    Pressure,
    Progress,
    Status,
    decode,
    encode,
)
from scotti.models.contract import ACTIONS
from scotti.models.ood import OOD_FLAGS

DOCS = Path(__file__).parent.parent / "docs"
STAMP: dict[str, Any] = {
    "seq": 7,
    "device_seq": DeviceSeq(left=65535, right=3),
    "device_time_us": 4_000_000_000,
    "host_wall_ns": 1_700_000_000_000_000_000,
    "host_mono_ns": 123_456_789,
    "predicted_for_mono_ns": 185_956_789,
    "latency_ms": 3.5,
    "flags": ["left_filled"],
    "unfamiliar_score": 12.5,
}


def pose() -> Pose:
    return Pose(**STAMP, keypoints=[[0.1 * i, 0.0, 1.0] for i in range(19)])


@pytest.mark.parametrize("fmt", ["json", "msgpack"])
def test_round_trip_both_formats(fmt: str) -> None:
    assert fmt in ("json", "msgpack")
    for payload in (
        pose(),
        Action(**STAMP, action="squat", confidence=0.9, probabilities={"squat": 0.9}),
        Pressure(**STAMP, rows=2, cols=1, downsample=16, left=b"\x01\x00\xff\x0f", right=b"\0" * 4),
    ):
        data = encode(payload, fmt)  # type: ignore[arg-type]
        assert decode(type(payload), data, fmt) == payload  # type: ignore[arg-type]


def test_json_is_plain_json_and_msgpack_has_binary_pressure() -> None:
    p = Pressure(**STAMP, rows=1, cols=2, downsample=16, left=b"\xfb\xff\x01\x00", right=b"")
    doc = json.loads(encode(p, "json"))
    assert doc["schema_version"] == 2
    assert doc["device_seq"] == {"left": 65535, "right": 3}
    assert base64.urlsafe_b64decode(doc["left"]) == b"\xfb\xff\x01\x00"
    assert msgpack.unpackb(encode(p, "msgpack"))["left"] == b"\xfb\xff\x01\x00"


def test_bad_payloads_are_rejected() -> None:
    with pytest.raises(ValidationError):
        Pose(**STAMP, keypoints=[[0.0, 0.0, 0.0]] * 18)  # 18 keypoints
    with pytest.raises(ValidationError):
        Action(**STAMP, action="squat", confidence=1.5, probabilities={})
    with pytest.raises(ValidationError):
        Status.model_validate({"state": "sleepy", "reasons": [], "source": "connected"})
    with pytest.raises(ValidationError):
        decode(Pose, b'{"schema_version": 2}', "json")
    with pytest.raises(ValidationError):  # a withheld action names one of the three flags
        Action(**STAMP, action=None, confidence=0.0, probabilities={}, withheld="asleep")  # type: ignore[arg-type]


def test_action_names_are_the_contracts_and_payloads_carry_standing() -> None:
    assert schemas.ACTION_NAMES == ACTIONS  # the schema's literal follows the model contract
    still = Progress(**STAMP, action="standing", progress=None, repetition=-1)
    doc = json.loads(encode(still, "json"))
    assert doc["schema_version"] == 3
    assert doc["progress"] is None
    assert decode(Progress, encode(still, "msgpack"), "msgpack") == still
    assert Action(**STAMP, action="standing", confidence=0.9, probabilities={}).schema_version == 3
    assert pose().schema_version == 2
    with pytest.raises(ValidationError):
        Action(**STAMP, action="sitting", confidence=0.9, probabilities={})
    with pytest.raises(ValidationError):  # a version-1 progress payload is not misread
        decode(
            Progress,
            encode(still, "json").replace(b'"schema_version":3', b'"schema_version":2'),
            "json",
        )
    schema = json.loads(schemas.json_schemas()["progress"])
    names = schema["properties"]["action"]["anyOf"][0]["enum"]
    assert names == list(ACTIONS)


def test_withheld_names_are_the_ood_flags_and_a_withheld_action_is_null() -> None:
    assert get_args(schemas.WithheldFlag) == OOD_FLAGS
    gone = Action(
        **{**STAMP, "flags": ["unloaded"], "unfamiliar_score": None},
        action=None,
        confidence=0.0,
        probabilities={},
        withheld="unloaded",
    )
    doc = json.loads(encode(gone, "json"))
    assert doc["action"] is None
    assert doc["withheld"] == "unloaded"
    assert doc["unfamiliar_score"] is None  # an uncalibrated model publishes null
    assert decode(Action, encode(gone, "msgpack"), "msgpack") == gone


def test_committed_docs_equal_the_generated_ones() -> None:
    for path, text in schemas.generated_files(DOCS).items():
        assert path.read_text(encoding="utf-8") == text, (
            f"{path} is stale: python -m scotti.daemon.mqtt.schemas --write"
        )


def test_doc_generator_replaces_only_its_section() -> None:
    doc = "# Title\n\nprose\n\n" + schemas.BEGIN + "\nstale section\n" + schemas.END + "\n\nafter\n"
    out = schemas.render_doc(doc)
    assert out.startswith("# Title\n\nprose\n\n")
    assert out.endswith("\n\nafter\n")
    assert "stale section" not in out  # ("old" is in "threshold")
    assert "| `pose` | [pose.schema.json](schemas/pose.schema.json) | 2 |" in out
    assert schemas.render_doc(out) == out


def test_the_doc_links_every_schema_file_the_generator_writes(tmp_path: Path) -> None:
    files = schemas.generated_files(tmp_path)
    written = {p.relative_to(tmp_path).as_posix() for p in files if p.suffix == ".json"}
    linked = set(re.findall(r"\]\((schemas/[^)]+)\)", schemas.render_doc_section()))
    assert linked == written
    assert len(linked) == len(schemas.json_schemas())  # one file per topic, none shared


def test_check_mode_reports_stale_files(tmp_path: Path) -> None:
    assert schemas.main(["--docs", str(tmp_path), "--check"]) == 1
    assert schemas.main(["--docs", str(tmp_path), "--write"]) == 0
    assert schemas.main(["--docs", str(tmp_path), "--check"]) == 0
    assert (tmp_path / "schemas" / "pose.schema.json").exists()


def test_health_bad_packets_is_the_decoders_own_count_of_dropped_packets() -> None:
    from scotti.daemon.mqtt.messages import dropped_packets
    from scotti.firmware_protocol.framing import StreamDecoder, encode_packet
    from scotti.firmware_protocol.packets import Foot

    from tests.support.sessions import frame_packets, synthetic_counts

    decoder = StreamDecoder()
    good = b"".join(
        encode_packet(p) for p in frame_packets(Foot.LEFT, 0, 0, synthetic_counts(0, 0))
    )
    bad_crc = bytearray(good[: len(good) // 4])
    bad_crc[5] ^= 0xFF
    decoder.feed(good + b"\x01\x02\x00" + bytes(bad_crc) + good)
    counters = decoder.counters
    assert counters.packets == 8
    assert counters.errors >= 2
    assert dropped_packets(counters.as_dict()) == counters.errors  # good packets not counted
    assert dropped_packets({}) == dropped_packets(None) == 0
