"""COBS: the reference examples, round trips and rejected frames."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scotti.firmware_protocol import cobs
from scotti.firmware_protocol.errors import BadCobsError

_RUN_254 = bytes(range(1, 255))  # 01 02 .. FE

# (decoded, encoded) pairs from the COBS article's example table.
EXAMPLES = [
    (b"", bytes.fromhex("01")),
    (bytes.fromhex("00"), bytes.fromhex("01 01")),
    (bytes.fromhex("00 00"), bytes.fromhex("01 01 01")),
    (bytes.fromhex("00 11 00"), bytes.fromhex("01 02 11 01")),
    (bytes.fromhex("11 22 00 33"), bytes.fromhex("03 11 22 02 33")),
    (bytes.fromhex("11 22 33 44"), bytes.fromhex("05 11 22 33 44")),
    (bytes.fromhex("11 00 00 00"), bytes.fromhex("02 11 01 01 01")),
    (_RUN_254, b"\xff" + _RUN_254),
    (b"\x00" + _RUN_254, bytes.fromhex("01 ff") + _RUN_254),
    (_RUN_254 + b"\xff", b"\xff" + _RUN_254 + bytes.fromhex("02 ff")),
    (bytes(range(2, 256)) + b"\x00", b"\xff" + bytes(range(2, 256)) + bytes.fromhex("01 01")),
    (bytes(range(3, 256)) + bytes.fromhex("00 01"), b"\xfe" + bytes(range(3, 256)) + b"\x02\x01"),
]


@pytest.mark.parametrize(("decoded", "encoded"), EXAMPLES)
def test_known_answers(decoded: bytes, encoded: bytes) -> None:
    assert cobs.encode(decoded) == encoded
    assert cobs.decode(encoded) == decoded


def test_decoder_accepts_the_non_minimal_form_of_a_final_full_block() -> None:
    assert cobs.decode(b"\xff" + _RUN_254 + b"\x01") == _RUN_254


@pytest.mark.parametrize(
    "frame",
    [bytes.fromhex("05 11 22"), bytes.fromhex("02 11 00 01"), bytes.fromhex("00"), b"\xff\x01"],
)
def test_rejects_bad_frames(frame: bytes) -> None:
    with pytest.raises(BadCobsError):
        cobs.decode(frame)


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=1200))
def test_round_trip_has_no_zero_and_bounded_overhead(data: bytes) -> None:
    encoded = cobs.encode(data)
    assert 0 not in encoded
    assert len(encoded) <= cobs.max_encoded_len(len(data))
    assert cobs.decode(encoded) == data
