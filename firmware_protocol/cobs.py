"""Consistent Overhead Byte Stuffing (Cheshire & Baker, 1999).

COBS rewrites a packet so that it contains no 0x00 byte; 0x00 then marks the
end of every packet on the wire, and a reader that starts mid-stream (or
after noise) is back in step at the next 0x00. The encoded form is at most
``ceil(n / 254)`` bytes longer than the packet (``max_encoded_len``).

Encoding is the minimal form of the reference C code: a final block of
exactly 254 bytes is not followed by an extra 0x01 code. The decoder accepts
both forms.
"""

from __future__ import annotations

import importlib
import re
from collections.abc import Sequence
from typing import Any, Final

import numpy as np
import numpy.typing as npt
from scotti.firmware_protocol.errors import BadCobsError

try:  # optional, compiled (the [fast] extra); the ``*_fallback`` functions stand in without it
    _compiled: Any = importlib.import_module("cobs.cobs")
except ImportError:
    _compiled = None

MAX_BLOCK = 254  # data bytes carried by a 0xFF code, which has no implied zero after it
_FULL_CODE = 0xFF  # code byte of a full block


def max_encoded_len(decoded_len: int) -> int:
    """Longest COBS encoding of ``decoded_len`` bytes (without the delimiter)."""
    return decoded_len + decoded_len // MAX_BLOCK + 1


def encode(data: bytes) -> bytes:
    """COBS-encode ``data``; the result contains no 0x00 (delimiter not added)."""
    out = bytearray()
    segments = bytes(data).split(b"\x00")
    last = len(segments) - 1
    for index, segment in enumerate(segments):
        start = 0
        while len(segment) - start >= MAX_BLOCK:
            out.append(_FULL_CODE)
            out += segment[start : start + MAX_BLOCK]
            start += MAX_BLOCK
        rest = len(segment) - start
        if index == last and rest == 0 and start > 0:
            break  # data ends with a full block: the minimal form adds no 0x01
        out.append(rest + 1)
        out += segment[start:]
    return bytes(out)


def encode_batch(chunks: Sequence[bytes]) -> list[bytes]:
    """``[encode(c) for c in chunks]``, byte for byte, vectorised with numpy.

    Chunks of one length are encoded together: each 0x00 becomes the
    distance to the next 0x00 (or the end) and a code byte goes in front. A
    chunk with a run of 254+ non-zero bytes (which COBS splits into full
    blocks) goes through ``encode`` itself. Several times faster than
    ``encode`` on many short, zero-heavy chunks (rows of pressure samples).
    """
    out: list[bytes] = [b""] * len(chunks)
    by_length: dict[int, list[int]] = {}
    for i, chunk in enumerate(chunks):
        by_length.setdefault(len(chunk), []).append(i)
    for length, idx in by_length.items():
        a = np.frombuffer(b"".join([chunks[i] for i in idx]), np.uint8).reshape(len(idx), length)
        for i, encoded in zip(idx, encode_rows(a), strict=True):
            out[i] = encoded
    return out


def encode_rows(a: np.ndarray) -> list[bytes]:
    """``[encode(row) for row in a]`` for a (n, length) uint8 array.

    With the compiled ``cobs`` package installed, each row goes through it
    (about a microsecond a kilobyte; the same bytes as ``encode``); without
    it, ``encode_rows_fallback``.
    """
    if _compiled is None:
        return encode_rows_fallback(a)
    return encode_rows_compiled(a)


def encode_rows_compiled(a: np.ndarray) -> list[bytes]:
    """``encode_rows`` through the compiled ``cobs`` package (it must be installed)."""
    assert _compiled is not None
    c_encode = _compiled.encode
    n, length = a.shape
    if length == 0:
        return [c_encode(b"") for _ in range(n)]
    data = np.ascontiguousarray(a, dtype=np.uint8).tobytes()
    return [c_encode(data[i : i + length]) for i in range(0, n * length, length)]


def encode_rows_fallback(a: np.ndarray) -> list[bytes]:
    """``[encode(row) for row in a]`` for a (n, length) uint8 array, vectorised with numpy.

    Each row is laid out as [0, row..., 0]: a zero in front for the code
    byte and one behind for the end. Every zero but the last then becomes
    the distance to the next zero, and the last is dropped. A row in which
    some distance exceeds 254 (a run COBS splits into full blocks) goes
    through ``encode`` itself.
    """
    n, length = a.shape
    width = length + 2
    ext = np.zeros((n, width), np.uint8)
    ext[:, 1:-1] = a
    flat = ext.reshape(-1)
    zeros = np.flatnonzero(flat == 0)
    step = np.diff(zeros)  # within a row: to the next zero; at a row's end: to the next row
    flat[zeros[:-1]] = np.minimum(step, 255).astype(np.uint8)  # ends are dropped below
    ends = (zeros[:-1] % width) == width - 1
    too_long = np.flatnonzero((step > MAX_BLOCK) & ~ends)
    slow = set((zeros[too_long] // width).tolist())
    body = ext[:, :-1].tobytes()
    stride = length + 1
    return [
        encode(a[row].tobytes()) if row in slow else body[row * stride : (row + 1) * stride]
        for row in range(n)
    ]


def decode(frame: bytes) -> bytes:
    """Decode one COBS frame (the bytes between two delimiters).

    Raises ``BadCobsError`` when a code byte is zero or points past the end.
    """
    result = decode_many([frame])[0]
    if isinstance(result, BadCobsError):
        raise result
    return result


def decode_many(frames: Sequence[bytes]) -> list[bytes | BadCobsError]:
    """``decode`` of every frame; an invalid frame gives its error instead.

    With the compiled ``cobs`` package installed (``pip install 'scotti[fast]'``,
    it builds from source: a C compiler is needed) each frame takes about half
    a microsecond; without it, ``decode_fallback`` (tens of microseconds). Both
    give the same bytes and, for an invalid frame, the same error as
    ``_decode_one``.
    """
    if _compiled is None:
        return decode_fallback(frames)
    return decode_compiled(frames)


def decode_compiled(frames: Sequence[bytes]) -> list[bytes | BadCobsError]:
    """``decode_many`` through the compiled ``cobs`` package (it must be installed)."""
    assert _compiled is not None
    c_decode, c_error = _compiled.decode, _compiled.DecodeError
    out: list[bytes | BadCobsError] = []
    for frame in frames:
        try:
            out.append(c_decode(frame))
        except c_error:
            out.append(_decode_one(frame))  # our error, with its offset
    return out


def decode_fallback(frames: Sequence[bytes]) -> list[bytes | BadCobsError]:
    """``decode_many`` without the compiled package.

    Pressure rows are mostly zeros, so a frame is mostly one- and two-byte
    blocks: any decoder in Python pays per block. A few frames (what one
    serial read completes) go one by one: a frame that is mostly code-1 blocks
    (zeros: more than half its bytes are 0x01) through ``_decode_tokens``, which
    lets the regular expression engine find its nonzero runs, about 4x faster
    on insole frames; any other through ``_decode_joined``, which only slices
    blocks and joins them with zeros. Many frames at once (a session read in
    bulk) go through ``_decode_lockstep``, one numpy step per block for all
    frames together. Invalid frames (rare: line noise) are decoded again by
    ``_decode_one`` so their error names the offset, as it always did.
    """
    if len(frames) < _LOCKSTEP_MIN:
        return [
            _decode_tokens(frame) if 2 * frame.count(1) > len(frame) else _decode_joined(frame)
            for frame in frames
        ]
    return _decode_lockstep(frames)


_LOCKSTEP_MIN: Final = 16  # frames from which one numpy step for all beats a loop per frame

# One COBS block with code c (2..254), its c - 1 data bytes, and the code-1 blocks (zeros)
# after it; or a frame's leading code-1 blocks. The code byte picks the branch, so a
# frame's tokens follow its blocks, found by the regular expression engine in C.
_TOKEN: Final = re.compile(
    b"|".join(
        [b"\\x01+"]
        + [b"%s(?s:.{%d})\\x01*" % (re.escape(bytes([c])), c - 1) for c in range(2, 255)]
    )
)


def _decode_tokens(frame: bytes) -> bytes | BadCobsError:
    """One frame as a few tokens (``_TOKEN``): a pressure row is mostly zeros, each a
    code-1 block, so a token holds a nonzero run and the zeros after it. A frame
    the tokens do not cover exactly (invalid), or with a full block, goes to
    ``_decode_joined``."""
    if 0 in frame or _FULL_CODE in frame:
        return _decode_joined(frame)
    tokens = _TOKEN.findall(frame)
    if sum(map(len, tokens)) != len(frame):  # a block runs past the end: invalid
        return _decode_one(frame)
    pieces = [
        # its data, then a zero for its block and one per code-1 block after it
        token[1 : token[0]] + bytes(len(token) - token[0] + 1)
        if token[0] != 1
        else bytes(len(token))  # the leading code-1 blocks: a zero each
        for token in tokens
    ]
    return b"".join(pieces)[:-1]  # no zero after the last block


def _decode_joined(frame: bytes) -> bytes | BadCobsError:
    """One frame: the blocks sliced out and joined with the zeros they stand for."""
    if 0 in frame:  # memchr: a zero code byte or a zero inside a block
        return _decode_one(frame)
    blocks: list[bytes] = []
    append, size, i = blocks.append, len(frame), 0
    while i < size:
        end = i + frame[i]
        append(frame[i + 1 : end])
        i = end
    # Past the end (invalid), or a full block (254 data bytes: code 0xFF, no zero after
    # it; only in frames that long): the block-by-block decoder does those.
    if i > size or (size > MAX_BLOCK and MAX_BLOCK in map(len, blocks)):
        return _decode_one(frame)
    return b"\x00".join(blocks)


def _decode_lockstep(frames: Sequence[bytes]) -> list[bytes | BadCobsError]:
    """Many frames: their code bytes found by numpy steps, then one pass over all.

    Every code byte but the first of its frame becomes the zero it stands for,
    unless the block before it was full (0xFF); the data bytes stay.
    """
    count = len(frames)
    lengths = np.fromiter((len(f) for f in frames), dtype=np.int64, count=count)
    ends = np.cumsum(lengths + 1) - 1  # each frame is followed by one end slot
    starts = ends - lengths
    buf = np.frombuffer(b"\x00".join(frames) + b"\x00", dtype=np.uint8)
    bad = np.fromiter((0 in f for f in frames), dtype=bool, count=count)  # memchr speed
    codes = _codes_lockstep(buf, starts, ends, bad)
    frame_of = np.repeat(np.arange(count), lengths + 1)
    is_end = np.zeros(buf.size, dtype=bool)
    is_end[ends] = True
    after_full = np.zeros(codes.size, dtype=bool)
    after_full[1:] = buf[codes[:-1]] == _FULL_CODE
    first = np.zeros(buf.size, dtype=bool)
    first[starts] = True
    keep = ~is_end
    keep[codes] = ~first[codes] & ~after_full
    out = buf.copy()
    out[codes] = 0
    data = out[keep].tobytes()
    sizes = np.bincount(frame_of[keep], minlength=count)
    offsets = np.concatenate(([0], np.cumsum(sizes))).tolist()
    return [
        _decode_one(frames[i]) if bad[i] else data[offsets[i] : offsets[i + 1]]
        for i in range(count)
    ]


def _codes_lockstep(
    buf: np.ndarray, starts: np.ndarray, ends: np.ndarray, bad: np.ndarray
) -> npt.NDArray[np.int64]:
    """Positions of the code bytes, every frame one block further per numpy step."""
    frame = np.flatnonzero(~bad & (starts < ends))
    pos, limit = starts[frame], ends[frame]
    chain = [pos]
    while pos.size:
        pos = pos + buf[pos]
        over = pos > limit
        if over.any():  # a block past its frame's end: that frame is invalid
            bad[frame[over]] = True
        going = pos < limit
        pos, limit, frame = pos[going], limit[going], frame[going]
        chain.append(pos)
    codes = np.sort(np.concatenate(chain))
    if bad.any():  # drop the invalid frames' code bytes (they are decoded again)
        codes = codes[~bad[np.searchsorted(ends, codes)]]
    return codes


def _decode_one(frame: bytes) -> bytes | BadCobsError:
    """The reference decoder, one block at a time: the error, with its offset."""
    out = bytearray()
    size = len(frame)
    i = 0
    while i < size:
        code = frame[i]
        if code == 0:
            msg = f"zero code byte at offset {i}"
            return BadCobsError(msg)
        end = i + code
        if end > size:
            msg = f"block at offset {i} needs {code - 1} bytes, {size - i - 1} left"
            return BadCobsError(msg)
        block = frame[i + 1 : end]
        if 0 in block:
            msg = f"0x00 inside the block at offset {i}"
            return BadCobsError(msg)
        out += block
        i = end
        if code != _FULL_CODE and i < size:
            out.append(0)  # every block shorter than 254 ends with an implied zero
    return bytes(out)
