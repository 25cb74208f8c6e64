"""Packets on the wire: COBS-encoded, each followed by one 0x00 delimiter.

``StreamDecoder`` takes bytes in whatever chunks the serial port delivers and
returns packets and ``DecodeError`` values. It never raises on input: after
garbage it is back in step at the next delimiter, and it never holds more
than one maximal encoded packet in memory.
"""

from __future__ import annotations

import zlib
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Final, TypeAlias

import numpy as np
from scotti.firmware_protocol import cobs
from scotti.firmware_protocol.errors import (
    BadCobsError,
    DecodeError,
    PacketValueError,
    TooLongError,
)
from scotti.firmware_protocol.packets import (
    CLOCK_MODULUS,
    CRC_LEN,
    MAX_PACKET_LEN,
    MAX_SAMPLE_BITS,
    SEQ_MODULUS,
    TYPE_FRAME_ROWS,
    VERSION,
    FrameRows,
    Packet,
    RawRows,
    parse_packet,
    raw_rows,
)

Item: TypeAlias = RawRows | Packet | DecodeError  # what ``StreamDecoder.feed_raw`` returns
DELIMITER: Final = 0x00  # ends every COBS-encoded packet on the wire
MAX_ENCODED_LEN: Final = cobs.max_encoded_len(MAX_PACKET_LEN)  # longest legal run (2057 bytes)


def encode_packet(packet: Packet) -> bytes:
    """The bytes the board sends for ``packet``: COBS(packet) + 0x00."""
    return cobs.encode(packet.to_bytes()) + b"\x00"


def encode_packets(packets: Sequence[Packet]) -> list[bytes]:
    """``[encode_packet(p) for p in packets]``, byte for byte, COBS vectorised."""
    return [e + b"\x00" for e in cobs.encode_batch([p.to_bytes() for p in packets])]


# The FRAME_ROWS header as numpy lays it out, for encoding many packets at once:
# [version:1] [type:1] [foot:1] [seq:2] [board_clock_us:4] [rows:1] [cols:1]
# [sample_bits:1] [row_start:1] [row_count:1]  (packed, little endian)
_WHOLE_FRAME_HEAD: Final = np.dtype(
    [
        ("version", "u1"),
        ("type", "u1"),
        ("foot", "u1"),
        ("seq", "<u2"),
        ("clock", "<u4"),
        ("rows", "u1"),
        ("cols", "u1"),
        ("bits", "u1"),
        ("row_start", "u1"),
        ("row_count", "u1"),
    ]
)


def encode_whole_frames(
    feet: Sequence[int] | np.ndarray,
    seqs: Sequence[int] | np.ndarray,
    clocks_us: Sequence[int] | np.ndarray,
    frames: np.ndarray,
    sample_bits: int,
) -> list[bytes]:
    """Wire bytes of one FRAME_ROWS packet per frame carrying all its rows, many at once.

    Byte for byte ``encode_packet(FrameRows(foot, seq, clock, rows, cols, sample_bits,
    0, frame))`` for each, checked once for the whole batch (``frames``: (n, rows,
    cols) integers) instead of once per packet: what an importer writing hours
    of frames needs.
    """
    f = np.asarray(frames)
    n, rows, cols = f.shape
    length = _WHOLE_FRAME_HEAD.itemsize + 2 * rows * cols + CRC_LEN
    if f.dtype.kind not in "ui" or not (1 <= rows <= 255 and 1 <= cols <= 255):
        msg = f"frames must be integers (n, rows<=255, cols<=255), got {f.dtype} {f.shape}"
        raise PacketValueError(msg)
    if not 1 <= sample_bits <= MAX_SAMPLE_BITS or length > MAX_PACKET_LEN:
        msg = f"sample_bits={sample_bits} or a {length}-byte packet is outside the protocol"
        raise PacketValueError(msg)
    if f.size and (int(f.min()) < 0 or int(f.max()) >> sample_bits):
        msg = f"sample values must fit {sample_bits} bits"
        raise PacketValueError(msg)
    seq = np.asarray(seqs, dtype=np.int64)
    clock = np.asarray(clocks_us, dtype=np.int64)
    foot = np.asarray(feet, dtype=np.int64)
    if ((seq < 0) | (seq >= SEQ_MODULUS)).any() or ((clock < 0) | (clock >= CLOCK_MODULUS)).any():
        msg = "seq must be 0..65535 and board_clock_us 0..2**32-1"
        raise PacketValueError(msg)
    if ((foot != 0) & (foot != 1)).any():
        msg = "foot must be 0 (left) or 1 (right)"
        raise PacketValueError(msg)
    head = np.zeros(n, dtype=_WHOLE_FRAME_HEAD)
    head["version"], head["type"], head["foot"] = VERSION, TYPE_FRAME_ROWS, foot
    head["seq"], head["clock"] = seq, clock
    head["rows"], head["cols"], head["bits"], head["row_count"] = rows, cols, sample_bits, rows
    packets = np.empty((n, length), dtype=np.uint8)
    body = _WHOLE_FRAME_HEAD.itemsize + 2 * rows * cols
    packets[:, : _WHOLE_FRAME_HEAD.itemsize] = head.view(np.uint8).reshape(n, -1)
    samples = np.ascontiguousarray(f, dtype="<u2").reshape(n, -1).view(np.uint8)
    packets[:, _WHOLE_FRAME_HEAD.itemsize : body] = samples
    raw = packets.reshape(-1).data  # a view: slicing it copies nothing
    crcs = [zlib.crc32(raw[i * length : i * length + body]) for i in range(n)]
    packets[:, body:] = np.array(crcs, dtype="<u4").view(np.uint8).reshape(n, CRC_LEN)
    return [e + b"\x00" for e in cobs.encode_rows(packets)]


@dataclass
class DecoderCounters:
    """What a ``StreamDecoder`` has seen since it was made (all only grow)."""

    packets: int = 0  # packets decoded and returned
    bytes_in: int = 0  # every byte fed in
    bytes_discarded: int = 0  # bytes (delimiters included) that did not become a packet
    bad_cobs: int = 0  # runs between delimiters that are not valid COBS
    too_long: int = 0  # runs longer than MAX_ENCODED_LEN, or packets over MAX_PACKET_LEN
    bad_crc: int = 0  # packets whose CRC-32 did not match
    bad_version: int = 0  # packets of another protocol version
    unknown_type: int = 0  # packets of a type this host does not know (skipped)
    malformed: int = 0  # packets of a known type whose body breaks the spec

    @property
    def errors(self) -> int:
        """Every packet or run that was dropped, whatever the reason."""
        return (
            self.bad_cobs
            + self.too_long
            + self.bad_crc
            + self.bad_version
            + self.unknown_type
            + self.malformed
        )

    def as_dict(self) -> dict[str, int]:
        return asdict(self)


class StreamDecoder:
    """Bytes in, ``Packet`` or ``DecodeError`` values out (sans-I/O, never raises).

    A run of bytes longer than the longest legal encoded packet is dropped
    (counted once as ``too_long``) and everything up to the next delimiter
    is skipped without being stored.
    """

    def __init__(self, max_packet_len: int = MAX_PACKET_LEN) -> None:
        self.max_packet_len = max_packet_len
        self.max_encoded_len = cobs.max_encoded_len(max_packet_len)
        self.counters = DecoderCounters()
        self._buffer = bytearray()  # bytes since the last delimiter, at most max_encoded_len
        self._skipping = False  # inside an over-long run: drop until the next delimiter

    @property
    def pending(self) -> int:
        """Bytes held while waiting for the next delimiter."""
        return len(self._buffer)

    def feed(self, data: bytes | bytearray | memoryview) -> list[Packet | DecodeError]:
        """Take the next bytes of the stream; return what they completed, in order."""
        return [
            FrameRows.from_raw(item) if isinstance(item, tuple) else item
            for item in self.feed_raw(data)
        ]

    def feed_raw(self, data: bytes | bytearray | memoryview) -> list[Item]:
        """``feed``, with each FRAME_ROWS packet of the common case (``raw_rows``) as its
        header and bytes, not yet a ``FrameRows``: what the frame path's assembler takes.

        The chunk is split at its delimiters in one call, and the packets it completes
        are COBS-decoded together (``cobs.decode_many``): no Python loop per byte or block.
        """
        chunk = bytes(data)
        counters = self.counters
        counters.bytes_in += len(chunk)
        runs = chunk.split(b"\x00")
        tail = runs.pop()  # after the last delimiter: the start of a packet still coming
        out: list[Item] = []
        if runs:
            if self._skipping:  # the end of an over-long run: dropped, counted already
                counters.bytes_discarded += len(runs[0]) + 1
                self._skipping = False
                runs[0] = b""
            elif self._buffer:
                self._buffer += runs[0]
                runs[0] = bytes(self._buffer)
                self._buffer.clear()
            if b"" in runs:  # an empty run (0x00 0x00) is idle padding
                runs = [run for run in runs if run]
            if runs:
                if max(map(len, runs)) > self.max_encoded_len:
                    self._decode_some(runs, out)
                else:
                    self._decode(runs, out)
        if tail:
            self._keep(tail, out)
        return out

    def _decode(self, frames: list[bytes], out: list[Item]) -> None:
        """COBS frames (each at most ``max_encoded_len``) -> packets or errors, counted."""
        counters = self.counters
        limit = self.max_packet_len
        common = 0
        for frame, decoded in zip(frames, cobs.decode_many(frames), strict=True):
            if type(decoded) is bytes and len(decoded) <= limit:
                raw = raw_rows(decoded)
                if raw is not None:
                    out.append(raw)
                    common += 1
                    continue
            try:
                if isinstance(decoded, BadCobsError):
                    raise decoded
                if len(decoded) > limit:
                    msg = f"packet of {len(decoded)} bytes exceeds {limit}"
                    raise TooLongError(msg)
                out.append(parse_packet(decoded))
                counters.packets += 1
            except DecodeError as exc:
                setattr(counters, exc.reason, getattr(counters, exc.reason) + 1)
                counters.bytes_discarded += len(frame) + 1
                out.append(exc)
        counters.packets += common

    def _decode_some(self, frames: list[bytes], out: list[Item]) -> None:
        """``_decode``, where some runs are longer than a packet can be (dropped, counted)."""
        batch: list[bytes] = []
        for frame in frames:
            if len(frame) > self.max_encoded_len:
                self._decode(batch, out)
                batch = []
                out.append(self._too_long(len(frame) + 1))
            else:
                batch.append(frame)
        self._decode(batch, out)

    def reset(self) -> None:
        """Forget a partial packet (the port was reopened); its bytes count as discarded."""
        self.counters.bytes_discarded += len(self._buffer)
        self._buffer.clear()
        self._skipping = False

    def _keep(self, tail: bytes, out: list[Item]) -> None:
        if self._skipping:
            self.counters.bytes_discarded += len(tail)
            return
        if len(self._buffer) + len(tail) > self.max_encoded_len:
            out.append(self._too_long(len(self._buffer) + len(tail)))
            self._buffer.clear()
            self._skipping = True
            return
        self._buffer += tail

    def _too_long(self, discarded: int) -> DecodeError:
        self.counters.too_long += 1
        self.counters.bytes_discarded += discarded
        msg = f"more than {self.max_encoded_len} bytes without a delimiter"
        return TooLongError(msg)


def decode_all(data: bytes) -> tuple[list[Packet], DecoderCounters]:
    """Decode a whole byte string at once; returns the packets and the counters."""
    decoder = StreamDecoder()
    items = decoder.feed(data)
    return [item for item in items if not isinstance(item, DecodeError)], decoder.counters
