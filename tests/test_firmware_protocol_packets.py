"""Packets: known answers, CRC definition, round trips and every rejected field."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scotti.firmware_protocol.errors import (
    BadCrcError,
    BadVersionError,
    DecodeError,
    MalformedError,
    PacketValueError,
    TooLongError,
    UnknownTypeError,
)
from scotti.firmware_protocol.packets import (
    MAX_PACKET_LEN,
    TYPE_FRAME_ROWS,
    VERSION,
    BoardStatus,
    Foot,
    FrameRows,
    InsoleStatus,
    crc32,
    frame_blocks,
    parse_packet,
    try_parse_packet,
)

from tests.support.protocol import pattern_frame, status, whole_frame

TINY = FrameRows(Foot.LEFT, 0x0102, 0x03040506, 2, 2, 12, 1, np.array([[0x123, 0xABC]]))
TINY_BYTES = bytes.fromhex(
    "01 01"  # version 1, type FRAME_ROWS
    " 00 02 01 06 05 04 03"  # foot left, seq 0x0102, board clock 0x03040506
    " 02 02 0c 01 01"  # rows 2, cols 2, 12 bits, row_start 1, row_count 1
    " 23 01 bc 0a"  # samples 0x0123 0x0abc
    " 93 5f 61 1f"  # crc32 0x1f615f93
)
STATUS_BYTES = bytes.fromhex(
    "01 02"  # version 1, type BOARD_STATUS
    " 10 0e 00 00  e8 03 00 00  02 00 00 00  01 00 00 00"  # uptime 3600 s, rx 1000, crc 2, ovf 1
    " 74 0e 40 c6 01 05 00 00 00"  # left: 3700 mV, 64 %, -58 dBm, link up, 5 lost
    " 00 00 ff 80 00 00 00 00 00"  # right: all unknown, link down
    " 47 93 cb 14"
)


def reference_crc32(data: bytes) -> int:
    """CRC-32 exactly as PROTOCOL.md words it, bit by bit (independent of zlib)."""
    crc = 0xFFFFFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ (0xEDB88320 if crc & 1 else 0)
    return crc ^ 0xFFFFFFFF


def test_crc_matches_the_written_definition_and_check_value() -> None:
    assert crc32(b"123456789") == 0xCBF43926 == reference_crc32(b"123456789")
    assert crc32(TINY_BYTES[:-4]) == reference_crc32(TINY_BYTES[:-4]) == 0x1F615F93


def test_frame_rows_known_answer() -> None:
    assert TINY.to_bytes() == TINY_BYTES
    parsed = FrameRows.from_bytes(TINY_BYTES)
    assert parsed == TINY
    assert (parsed.row_count, parsed.row_start, parsed.geometry) == (1, 1, (2, 2, 12))
    assert parsed.samples.tolist() == [[0x123, 0xABC]]


def test_board_status_known_answer() -> None:
    assert status().to_bytes() == STATUS_BYTES
    parsed = BoardStatus.from_bytes(STATUS_BYTES)
    assert parsed == status()
    assert parsed.right.battery_pct is None
    assert parsed.insole(Foot.LEFT).rssi_dbm == -58


@pytest.mark.parametrize(
    "packet",
    [
        whole_frame(),
        whole_frame(Foot.RIGHT, seq=65535, clock=0xFFFFFFFF),
        FrameRows(Foot.RIGHT, 7, 0, 32, 22, 16, 24, np.full((8, 22), 0xFFFF, np.uint16)),
        FrameRows(Foot.LEFT, 0, 0, 1, 1, 1, 0, np.zeros((1, 1), np.uint16)),
        status(),
        BoardStatus(),
        BoardStatus(0xFFFFFFFF, 0xFFFFFFFF, 0, 0, InsoleStatus(0xFFFF, 100, 127, True, 2**32 - 1)),
    ],
)
def test_round_trip(packet: FrameRows | BoardStatus) -> None:
    assert parse_packet(packet.to_bytes()) == packet


def test_frame_rows_copies_and_freezes_samples() -> None:
    counts = pattern_frame()
    packet = FrameRows(Foot.LEFT, 1, 2, 32, 22, 12, 0, counts)
    counts[0, 0] = 4000
    assert packet.samples[0, 0] == 0
    assert not packet.samples.flags.writeable
    assert packet != FrameRows(Foot.LEFT, 1, 2, 32, 22, 12, 0, counts)


def test_frame_blocks_split_a_frame_in_row_order() -> None:
    blocks = frame_blocks(Foot.RIGHT, 9, 99, pattern_frame(), rows_per_block=8)
    assert [(b.row_start, b.row_count) for b in blocks] == [(0, 8), (8, 8), (16, 8), (24, 8)]
    assert np.array_equal(np.vstack([b.samples for b in blocks]), pattern_frame())
    assert [b.row_count for b in frame_blocks(Foot.LEFT, 0, 0, pattern_frame(), 10)] == [
        10,
        10,
        10,
        2,
    ]


@pytest.mark.parametrize(
    ("kwargs", "words"),
    [
        ({"seq": 65536}, "seq"),
        ({"board_clock_us": -1}, "board_clock_us"),
        ({"sample_bits": 17}, "sample_bits"),
        ({"sample_bits": 11}, "fit 11 bits"),  # the pattern holds values >= 2048
        ({"row_start": 25}, "outside a 32-row frame"),
        ({"cols": 21}, "shape"),
        ({"rows": 0}, "rows"),
    ],
)
def test_frame_rows_refuses_fields_outside_the_spec(kwargs: dict[str, int], words: str) -> None:
    fields: dict[str, object] = {
        "foot": Foot.LEFT,
        "seq": 1,
        "board_clock_us": 0,
        "rows": 32,
        "cols": 22,
        "sample_bits": 12,
        "row_start": 0,
        "samples": pattern_frame(rows=8),
    }
    fields.update(kwargs)
    with pytest.raises(PacketValueError, match=words):
        FrameRows(**fields)  # type: ignore[arg-type]


def test_frame_rows_refuses_a_packet_over_the_length_limit() -> None:
    with pytest.raises(PacketValueError, match="MAX_PACKET_LEN"):
        FrameRows(Foot.LEFT, 0, 0, 64, 22, 12, 0, np.zeros((64, 22), np.uint16))


def test_insole_status_refuses_out_of_range() -> None:
    with pytest.raises(PacketValueError, match="battery_pct"):
        InsoleStatus(battery_pct=101)
    with pytest.raises(PacketValueError, match="rssi_dbm"):
        InsoleStatus(rssi_dbm=-128)


def reseal(packet: bytes) -> bytes:
    """``packet`` with its CRC recomputed, to reach the checks after the CRC."""
    return packet[:-4] + crc32(packet[:-4]).to_bytes(4, "little")


@pytest.mark.parametrize(
    ("packet", "error", "words"),
    [
        (TINY_BYTES[:-1] + b"\x00", BadCrcError, "crc32"),
        (reseal(b"\x02" + TINY_BYTES[1:]), BadVersionError, "version 2"),
        (reseal(b"\x01\x7f" + TINY_BYTES[2:]), UnknownTypeError, "0x7f"),
        (bytes.fromhex("01 01 00"), MalformedError, "shortest"),
        (reseal(TINY_BYTES[:-6] + TINY_BYTES[-4:]), MalformedError, "need"),  # a sample short
        (reseal(TINY_BYTES[:2] + b"\x02" + TINY_BYTES[3:]), MalformedError, "foot=2"),
        (reseal(TINY_BYTES[:-5] + b"\x1a" + TINY_BYTES[-4:]), MalformedError, "fit 12 bits"),
        (reseal(TINY_BYTES[:12] + b"\x02" + TINY_BYTES[13:]), MalformedError, "outside"),
        (reseal(TINY_BYTES[:11] + b"\x00" + TINY_BYTES[12:]), MalformedError, "sample_bits"),
        (reseal(STATUS_BYTES[:-5] + STATUS_BYTES[-4:]), MalformedError, "BOARD_STATUS body"),
        (reseal(STATUS_BYTES[:20] + b"\x65" + STATUS_BYTES[21:]), MalformedError, "battery_pct"),
        (reseal(b"\x01\x01" + bytes(MAX_PACKET_LEN)), TooLongError, "exceeds"),
    ],
)
def test_rejected_packets_name_their_reason(
    packet: bytes, error: type[DecodeError], words: str
) -> None:
    with pytest.raises(error, match=words) as caught:
        parse_packet(packet)
    assert caught.value.reason in {
        "bad_crc",
        "bad_version",
        "unknown_type",
        "malformed",
        "too_long",
    }


def test_from_bytes_refuses_the_other_type() -> None:
    with pytest.raises(MalformedError, match="expected BOARD_STATUS"):
        BoardStatus.from_bytes(TINY_BYTES)
    with pytest.raises(MalformedError, match="expected FRAME_ROWS"):
        FrameRows.from_bytes(STATUS_BYTES)


def test_reserved_link_flag_bits_are_ignored() -> None:
    packet = reseal(STATUS_BYTES[:22] + b"\xfe" + STATUS_BYTES[23:])  # left flags: bit 0 clear
    assert BoardStatus.from_bytes(packet).left.link_up is False


@settings(max_examples=150, deadline=None)
@given(st.integers(1, 16), st.integers(1, 4), st.data())
def test_parser_accepts_samples_exactly_when_they_fit_their_bits(
    bits: int, row_count: int, data: st.DataObject
) -> None:
    # Built by hand: FrameRows itself refuses samples that do not fit.
    samples = data.draw(
        st.lists(st.integers(0, 0xFFFF), min_size=3 * row_count, max_size=3 * row_count)
    )
    body = struct.pack("<BHIBBBBB", 0, 1, 2, 8, 3, bits, 0, row_count)
    body += struct.pack(f"<{len(samples)}H", *samples)
    head_and_body = bytes((VERSION, TYPE_FRAME_ROWS)) + body
    packet = head_and_body + crc32(head_and_body).to_bytes(4, "little")
    fits = max(samples) < (1 << bits)
    result = try_parse_packet(packet)
    if fits:
        assert isinstance(result, FrameRows)
        assert result.samples.tolist() == [samples[i : i + 3] for i in range(0, len(samples), 3)]
    else:
        assert isinstance(result, MalformedError)
