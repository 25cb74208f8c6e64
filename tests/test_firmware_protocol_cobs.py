"""COBS: the reference examples, round trips and rejected frames."""

from __future__ import annotations

import numpy as np
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


# Edge inputs for the vectorised encoder: full blocks (254 non-zero bytes) and one
# more, at the start, between zeros and at the end; zeros only; nothing at all.
_EDGES = [
    b"",
    bytes(1),
    bytes(300),
    _RUN_254,
    _RUN_254 + b"\x01",
    bytes(range(1, 256)),  # 255 non-zero bytes
    b"\x00" + _RUN_254,
    b"\x00" + _RUN_254 + b"\x00",
    b"\x00" + _RUN_254[:-1] + b"\x00",  # 253: the longest block that needs no split
    b"\x07" * 253,
    b"\x07" * 600,
    b"\x00\x00" + b"\x07" * 510 + b"\x00",
]


def test_batch_encoding_equals_encode_on_edges() -> None:
    assert cobs.encode_batch(_EDGES) == [cobs.encode(c) for c in _EDGES]
    assert cobs.encode_batch([]) == []


@settings(max_examples=100, deadline=None)
@given(
    st.lists(
        st.one_of(
            st.binary(max_size=600),  # mostly non-zero: long runs, split blocks
            st.lists(st.sampled_from([0, 0, 0, 1, 255]), max_size=600).map(bytes),
        ),
        max_size=12,
    ),
    st.integers(0, 3),
)
def test_batch_encoding_equals_encode(chunks: list[bytes], copies: int) -> None:
    # Copies make several chunks of one length, encoded together in one array.
    batch = chunks * (copies + 1)
    assert cobs.encode_batch(batch) == [cobs.encode(c) for c in batch]


@pytest.mark.parametrize("length", [1, 2, 62, 253, 254, 255, 256, 509, 1100])
def test_batch_encoding_equals_encode_on_random_chunks_of_one_length(length: int) -> None:
    rng = np.random.default_rng(length)
    zero_share = rng.uniform(0.0, 1.0, (64, 1)) ** 3  # from no zeros to nearly all zeros
    data = rng.integers(1, 256, (64, length), dtype=np.uint8)
    data[rng.uniform(size=(64, length)) < zero_share] = 0
    chunks = [row.tobytes() for row in data]
    assert cobs.encode_batch(chunks) == [cobs.encode(c) for c in chunks]


_ROW_ENCODERS = [cobs.encode_rows, cobs.encode_rows_fallback]
if cobs._compiled is not None:  # the [fast] extra is installed
    _ROW_ENCODERS.append(cobs.encode_rows_compiled)


@pytest.mark.parametrize("encode_rows", _ROW_ENCODERS)
@settings(max_examples=60, deadline=None)
@given(
    st.integers(0, 700),
    st.integers(1, 12),
    st.floats(0.0, 1.0),
    st.integers(0, 2**32 - 1),
)
def test_row_encoding_equals_encode(
    encode_rows: object, length: int, rows: int, zero_share: float, seed: int
) -> None:
    rng = np.random.default_rng(seed)
    a = rng.integers(1, 256, (rows, length), dtype=np.uint8)
    a[rng.random((rows, length)) < zero_share] = 0
    assert callable(encode_rows)
    assert encode_rows(a) == [cobs.encode(row.tobytes()) for row in a]


@pytest.mark.parametrize("encode_rows", _ROW_ENCODERS)
@pytest.mark.parametrize("length", [253, 254, 255, 508, 509, 1100])
def test_row_encoding_of_full_blocks(encode_rows: object, length: int) -> None:
    """Runs of 254 non-zero bytes and more, ending where a block does or not."""
    a = np.full((3, length), 7, dtype=np.uint8)
    a[1, length // 2] = 0
    a[2, -1] = 0
    assert callable(encode_rows)
    assert encode_rows(a) == [cobs.encode(row.tobytes()) for row in a]


# --- many frames at once: the compiled package and the fallback -------------------

_DECODERS = [cobs.decode_fallback]
if cobs._compiled is not None:  # the [fast] extra is installed
    _DECODERS.append(cobs.decode_compiled)


def _reference(frames: list[bytes]) -> list[bytes | str]:
    """What the block-by-block decoder says, errors as their message."""
    out = [cobs._decode_one(f) for f in frames]
    return [r if isinstance(r, bytes) else str(r) for r in out]


def _same(decoded: list[bytes | BadCobsError]) -> list[bytes | str]:
    return [r if isinstance(r, bytes) else str(r) for r in decoded]


_pressure_like = st.lists(st.sampled_from([0, 0, 0, 0, 1, 7, 255]), max_size=700).map(bytes)


@pytest.mark.parametrize("decode_many", _DECODERS)
@settings(max_examples=120, deadline=None)
@given(
    st.lists(st.one_of(st.binary(max_size=600), _pressure_like), max_size=40),
    st.lists(st.binary(min_size=1, max_size=40), max_size=6),
)
def test_many_frames_decode_as_one_at_a_time(
    decode_many: object, data: list[bytes], garbage: list[bytes]
) -> None:
    # Valid encodings (full blocks, mostly-zero rows) mixed with garbage runs; 16 or
    # more frames take the fallback's numpy lockstep, fewer its block-joining loop.
    frames = [cobs.encode(d) for d in data] + garbage
    frames = frames[::2] + frames[1::2]
    assert callable(decode_many)
    assert _same(decode_many(frames)) == _reference(frames)
    assert _same(decode_many(frames[:5])) == _reference(frames[:5])


@pytest.mark.parametrize("decode_many", _DECODERS)
def test_many_frames_known_answers_and_rejections(decode_many: object) -> None:
    bad = [
        bytes.fromhex("05 11 22"),
        bytes.fromhex("02 11 00 01"),
        bytes.fromhex("00"),
        b"\xff\x01",
    ]
    frames = [e for _, e in EXAMPLES] * 2 + bad
    assert callable(decode_many)
    got = _same(decode_many(frames))
    assert got[: 2 * len(EXAMPLES)] == [d for d, _ in EXAMPLES] * 2
    assert got == _reference(frames)
    assert all(isinstance(g, str) for g in got[-len(bad) :])


# Mostly zeros, nonzero bytes below 255: the frames ``_decode_tokens`` is for.
_zero_heavy = st.lists(st.sampled_from([0, 0, 0, 0, 0, 1, 2, 7, 200]), max_size=900).map(bytes)


@settings(max_examples=300, deadline=None)
@given(_zero_heavy, st.integers(0, 10_000), st.integers(0, 255), st.booleans())
def test_zero_heavy_frames_decode_as_block_by_block_even_when_mangled(
    data: bytes, where: int, value: int, mangle: bool
) -> None:
    frame = cobs.encode(data)
    assert cobs._decode_tokens(frame) == data
    if mangle and frame:
        bad = bytearray(frame)
        bad[where % len(bad)] = value  # a code pointing elsewhere, a zero, a cut
        frame = bytes(bad[: len(bad) - where % 3])
    got, reference = cobs._decode_tokens(frame), cobs._decode_one(frame)
    assert str(got) == str(reference) if isinstance(reference, BadCobsError) else got == reference
