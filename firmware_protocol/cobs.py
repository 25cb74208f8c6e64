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

from collections.abc import Sequence

import numpy as np
from scotti.firmware_protocol.errors import BadCobsError

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
    """``[encode(row) for row in a]`` for a (n, length) uint8 array, vectorised.

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
    out = bytearray()
    size = len(frame)
    i = 0
    while i < size:
        code = frame[i]
        if code == 0:
            msg = f"zero code byte at offset {i}"
            raise BadCobsError(msg)
        end = i + code
        if end > size:
            msg = f"block at offset {i} needs {code - 1} bytes, {size - i - 1} left"
            raise BadCobsError(msg)
        block = frame[i + 1 : end]
        if 0 in block:
            msg = f"0x00 inside the block at offset {i}"
            raise BadCobsError(msg)
        out += block
        i = end
        if code != _FULL_CODE and i < size:
            out.append(0)  # every block shorter than 254 ends with an implied zero
    return bytes(out)
