"""The stream decoder: any chunking, garbage, over-long runs, and its counters."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scotti.firmware_protocol import cobs
from scotti.firmware_protocol.errors import (
    BadCobsError,
    BadCrcError,
    DecodeError,
    TooLongError,
    UnknownTypeError,
)
from scotti.firmware_protocol.framing import (
    MAX_ENCODED_LEN,
    StreamDecoder,
    decode_all,
    encode_packet,
)
from scotti.firmware_protocol.packets import Foot, Packet, crc32, frame_blocks

from tests.support.protocol import pattern_frame, status

PACKETS: list[Packet] = [
    block
    for seq in (65534, 65535, 0)  # across the sequence wrap
    for foot in (Foot.LEFT, Foot.RIGHT)
    for block in frame_blocks(foot, seq, (seq * 62_500) % 2**32, pattern_frame(salt=seq + foot))
]
PACKETS.insert(5, status())
STREAM = b"".join(encode_packet(p) for p in PACKETS)


def packets_of(items: list[Packet | DecodeError]) -> list[Packet]:
    return [item for item in items if not isinstance(item, DecodeError)]


def test_encoded_packet_is_cobs_plus_one_delimiter() -> None:
    wire = encode_packet(status())
    assert wire.endswith(b"\x00")
    assert wire.count(0) == 1
    assert cobs.decode(wire[:-1]) == status().to_bytes()


def test_whole_stream() -> None:
    decoder = StreamDecoder()
    assert decoder.feed(STREAM) == PACKETS
    assert decoder.counters.packets == len(PACKETS)
    assert decoder.counters.errors == 0
    assert decoder.counters.bytes_in == len(STREAM)
    assert decoder.pending == 0


def test_byte_by_byte() -> None:
    decoder = StreamDecoder()
    items = [item for i in range(len(STREAM)) for item in decoder.feed(STREAM[i : i + 1])]
    assert items == PACKETS


def test_random_chunks() -> None:
    rng = np.random.default_rng(7)
    cuts = np.sort(rng.choice(len(STREAM), size=200, replace=False))
    decoder = StreamDecoder()
    items = [
        item
        for chunk in np.split(np.frombuffer(STREAM, np.uint8), cuts)
        for item in decoder.feed(chunk.tobytes())
    ]
    assert items == PACKETS


def test_garbage_between_delimiters_costs_nothing_but_counts() -> None:
    garbage = b"\x00\x13\x37noise\xff\x00"
    decoder = StreamDecoder()
    items = decoder.feed(garbage + STREAM + b"trailing partial")
    assert packets_of(items) == PACKETS
    assert len(items) == len(PACKETS) + 1
    assert isinstance(items[0], DecodeError)
    assert decoder.counters.bytes_discarded == len(garbage) - 1  # leading 0x00 is padding
    assert decoder.pending == len(b"trailing partial")


def test_garbage_inside_one_packet_loses_only_that_packet() -> None:
    wires = [encode_packet(p) for p in PACKETS]
    broken = wires[3][:40] + b"\x00\x01\x02\x03" + wires[3][40:]  # noise with a delimiter
    items = StreamDecoder().feed(b"".join([*wires[:3], broken, *wires[4:]]))
    assert packets_of(items) == PACKETS[:3] + PACKETS[4:]
    flipped = bytearray(wires[3])
    flipped[100] ^= 0x40  # one flipped bit, no delimiter touched
    decoder = StreamDecoder()
    items = decoder.feed(b"".join([*wires[:3], bytes(flipped), *wires[4:]]))
    assert packets_of(items) == PACKETS[:3] + PACKETS[4:]
    assert decoder.counters.bad_crc + decoder.counters.bad_cobs == 1


def test_bad_crc_and_unknown_type_are_returned_and_counted() -> None:
    good = status().to_bytes()
    bad_crc = good[:-1] + bytes([good[-1] ^ 1])
    unknown_body = b"\x01\x80hello"
    unknown = unknown_body + crc32(unknown_body).to_bytes(4, "little")
    wire = b"".join(cobs.encode(p) + b"\x00" for p in (bad_crc, unknown, good))
    decoder = StreamDecoder()
    items = decoder.feed(wire)
    assert isinstance(items[0], BadCrcError)
    assert isinstance(items[1], UnknownTypeError)
    assert items[1].packet_type == 0x80
    assert items[2] == status()
    counters = decoder.counters
    assert (counters.bad_crc, counters.unknown_type, counters.packets) == (1, 1, 1)
    assert counters.bytes_discarded == len(cobs.encode(bad_crc)) + len(cobs.encode(unknown)) + 2


def test_bad_cobs_is_counted_under_both_names() -> None:
    decoder = StreamDecoder()
    items = decoder.feed(b"\x09\x01\x02\x00")
    assert isinstance(items[0], BadCobsError)
    assert decoder.counters.bad_cobs == 1


def test_over_long_run_is_dropped_without_being_stored() -> None:
    decoder = StreamDecoder()
    noise = b"\x55" * 1000
    items: list[Packet | DecodeError] = []
    for _ in range(10):  # 10 kB without a delimiter
        items += decoder.feed(noise)
        assert decoder.pending <= MAX_ENCODED_LEN
    assert len(items) == 1
    assert isinstance(items[0], TooLongError)
    items = decoder.feed(b"\x55\x00" + encode_packet(status()))
    assert items == [status()]
    assert decoder.counters.too_long == 1
    assert decoder.counters.bytes_discarded == 10_002


def test_run_of_exactly_the_longest_legal_packet_is_kept() -> None:
    decoder = StreamDecoder()
    run = b"\x02\x55" * (MAX_ENCODED_LEN // 2) + b"\x01"  # valid COBS, too long once decoded
    assert len(run) == MAX_ENCODED_LEN
    items = decoder.feed(run + b"\x00")
    assert isinstance(items[0], TooLongError)
    assert decoder.counters.bytes_discarded == MAX_ENCODED_LEN + 1


def test_reset_discards_a_partial_packet() -> None:
    decoder = StreamDecoder()
    wire = encode_packet(status())
    decoder.feed(wire[:10])
    decoder.reset()
    assert decoder.feed(wire) == [status()]
    assert decoder.counters.bytes_discarded == 10


def test_decode_all() -> None:
    packets, counters = decode_all(b"junk\x00" + STREAM)
    assert packets == PACKETS
    assert counters.errors == 1


@settings(max_examples=150, deadline=None)
@given(
    data=st.binary(max_size=6000),
    cuts=st.lists(st.integers(min_value=0, max_value=6000), max_size=20),
)
def test_any_bytes_in_any_chunks_give_packets_or_decode_errors(
    data: bytes, cuts: list[int]
) -> None:
    decoder = StreamDecoder()
    bounds = [0, *sorted(c for c in cuts if c <= len(data)), len(data)]
    for start, stop in itertools.pairwise(bounds):
        for item in decoder.feed(data[start:stop]):
            assert isinstance(item, Packet | DecodeError)
        assert decoder.pending <= MAX_ENCODED_LEN
    assert decoder.counters.bytes_in == len(data)
    assert decoder.counters.bytes_discarded + decoder.pending <= len(data)


@settings(max_examples=60, deadline=None)
@given(garbage=st.binary(max_size=3000), split=st.integers(min_value=0, max_value=len(STREAM)))
def test_any_garbage_then_a_delimiter_is_followed_by_every_packet(
    garbage: bytes, split: int
) -> None:
    decoder = StreamDecoder()
    items = decoder.feed(garbage + b"\x00" + STREAM[:split]) + decoder.feed(STREAM[split:])
    assert packets_of(items)[-len(PACKETS) :] == PACKETS


def test_whole_frames_encode_like_one_packet_each() -> None:
    from scotti.firmware_protocol.errors import PacketValueError
    from scotti.firmware_protocol.framing import encode_whole_frames
    from scotti.firmware_protocol.packets import FrameRows

    rng = np.random.default_rng(7)
    frames = rng.integers(0, 4096, (9, 32, 22)).astype(np.uint16)
    frames[:3] = 0
    frames[3:6] = 257  # every byte non-zero: full COBS blocks
    feet = [0, 1] * 4 + [0]
    seqs = rng.integers(0, 1 << 16, 9)
    clocks = rng.integers(0, 1 << 32, 9)
    got = encode_whole_frames(feet, seqs, clocks, frames, 12)
    expected = [
        encode_packet(FrameRows(Foot(f), int(s), int(c), 32, 22, 12, 0, x))
        for f, s, c, x in zip(feet, seqs, clocks, frames, strict=True)
    ]
    assert got == expected
    too_big = frames.copy()
    too_big[0, 0, 0] = 4096
    with pytest.raises(PacketValueError, match="12 bits"):
        encode_whole_frames(feet, seqs, clocks, too_big, 12)
