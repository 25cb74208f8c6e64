"""Packets of the receiver board (PROTOCOL.md), one frozen dataclass per type.

Every packet, before COBS framing, is

    # [version:1] [type:1] [body:n] [crc32:4 LE]

with the CRC-32 (zlib/IEEE) over version, type and body. All multi-byte
fields are little endian. This module is sans-I/O: bytes in, objects out.
"""

from __future__ import annotations

import enum
import struct
import zlib
from dataclasses import dataclass, field
from typing import Any, Final, TypeAlias, TypeVar

import numpy as np
from scotti.firmware_protocol.errors import (
    BadCrcError,
    BadVersionError,
    DecodeError,
    MalformedError,
    PacketValueError,
    TooLongError,
    UnknownTypeError,
)

VERSION: Final = 1  # protocol version byte; a packet of another version is counted and dropped
TYPE_FRAME_ROWS: Final = 0x01  # a block of rows of one foot's frame
TYPE_BOARD_STATUS: Final = 0x02  # battery, radio link and receiver counters
HEADER_LEN: Final = 2  # version + type
CRC_LEN: Final = 4  # CRC-32, little endian, last four bytes of every packet
MIN_PACKET_LEN: Final = HEADER_LEN + CRC_LEN  # a packet with an empty body
MAX_PACKET_LEN: Final = 2048  # longest packet before COBS; longer runs are discarded, never stored

# Frame geometry the insoles ship with; the parser always takes it from the packet.
DEFAULT_ROWS: Final = 32  # taxel rows per insole (equals models.contract.FRAME_ROWS)
DEFAULT_COLS: Final = 22  # taxel columns per insole (equals models.contract.FRAME_COLS)
DEFAULT_SAMPLE_BITS: Final = 12  # ADC bits per taxel (equals models.contract.SAMPLE_BITS)
MAX_SAMPLE_BITS: Final = 16  # samples travel as u16
SEQ_MODULUS: Final = 1 << 16  # frame sequence numbers wrap at 65536
CLOCK_MODULUS: Final = 1 << 32  # board clock (us) wraps at 2**32 (~71.6 min)

# FRAME_ROWS body: [foot:1] [seq:2] [board_clock_us:4] [rows:1] [cols:1] [sample_bits:1]
#                  [row_start:1] [row_count:1] [samples: row_count * cols * u16]
_FRAME_ROWS_HEAD: Final = struct.Struct("<BHIBBBBB")
SAMPLES_AT: Final = HEADER_LEN + _FRAME_ROWS_HEAD.size  # first sample byte in a packet
_WIRE_SAMPLE: Final = np.dtype("<u2")
# A frozen dataclass made from the wire in one step (its __setattr__ refuses, by design).
_new, _set = object.__new__, object.__setattr__
# BOARD_STATUS body: [uptime_s:4] [rx_packets:4] [radio_crc_errors:4] [overflows:4]
#                    then per insole, left then right, INSOLE_STATUS
_STATUS_HEAD: Final = struct.Struct("<IIII")
# INSOLE_STATUS: [battery_mv:2] [battery_pct:1] [rssi_dbm:1 i8] [link_flags:1] [packets_lost:4]
_INSOLE: Final = struct.Struct("<HBbBI")
BOARD_STATUS_BODY_LEN: Final = _STATUS_HEAD.size + 2 * _INSOLE.size  # 34 bytes

BATTERY_MV_UNKNOWN: Final = 0  # battery_mv on the wire when the insole has not reported
BATTERY_PCT_UNKNOWN: Final = 255  # battery_pct on the wire when unknown
RSSI_UNKNOWN: Final = -128  # rssi_dbm on the wire when no radio packet was heard yet
LINK_UP: Final = 0x01  # link_flags bit 0: the insole was heard within the last second

_U32: Final = 0xFFFFFFFF
# zlib.crc32 of a packet with its own CRC appended (little endian) is this constant for
# every packet whose CRC is right and no other: one call, no slice, checks a packet.
_CRC_RESIDUE: Final = 0x2144DF1C


class Foot(enum.IntEnum):
    LEFT = 0
    RIGHT = 1


_FEET: Final = (Foot.LEFT, Foot.RIGHT)  # by wire value, without an enum lookup
# For 8..15-bit samples: the high bytes (little endian) a sample may have, to delete
# from the high bytes there are (C speed, no numpy call per packet).
_HIGH_BYTES: Final = {bits: bytes(range(1 << (bits - 8))) for bits in range(8, MAX_SAMPLE_BITS)}


def crc32(data: bytes) -> int:
    """CRC-32/ISO-HDLC (zlib): reflected poly 0xEDB88320, init and xorout 0xFFFFFFFF."""
    return zlib.crc32(data) & _U32


def _seal(packet_type: int, body: bytes) -> bytes:
    head_and_body = bytes((VERSION, packet_type)) + body
    return head_and_body + crc32(head_and_body).to_bytes(CRC_LEN, "little")


def _check_range(name: str, value: int, low: int, high: int) -> None:
    if not low <= value <= high:
        msg = f"{name}={value} outside {low}..{high}"
        raise PacketValueError(msg)


@dataclass(frozen=True, eq=False)
class FrameRows:
    """``row_count`` rows of one foot's frame, starting at ``row_start`` (type 0x01)."""

    foot: Foot
    seq: int  # u16 frame sequence number, the same in every block of one frame
    board_clock_us: int  # u32 insole clock when the frame was sampled
    rows: int  # rows of the whole frame
    cols: int  # columns of the whole frame
    sample_bits: int  # significant bits of each sample
    row_start: int  # first row carried here
    samples: np.ndarray = field(repr=False)  # (row_count, cols) uint16, row-major, read-only

    def __post_init__(self) -> None:
        object.__setattr__(self, "foot", Foot(self.foot))
        _check_range("seq", self.seq, 0, SEQ_MODULUS - 1)
        _check_range("board_clock_us", self.board_clock_us, 0, CLOCK_MODULUS - 1)
        _check_range("rows", self.rows, 1, 255)
        _check_range("cols", self.cols, 1, 255)
        _check_range("sample_bits", self.sample_bits, 1, MAX_SAMPLE_BITS)
        arr = np.asarray(self.samples)
        if arr.dtype.kind not in "ui" or arr.ndim != 2 or arr.shape[1] != self.cols:
            msg = f"samples must be integers of shape (row_count, {self.cols}), got {arr.dtype}"
            msg += f" {arr.shape}"
            raise PacketValueError(msg)
        row_count = arr.shape[0]
        _check_range("row_count", row_count, 1, 255)
        if self.row_start + row_count > self.rows or self.row_start < 0:
            msg = f"rows {self.row_start}..{self.row_start + row_count - 1} outside a"
            msg += f" {self.rows}-row frame"
            raise PacketValueError(msg)
        if arr.size and (int(arr.min()) < 0 or int(arr.max()) >> self.sample_bits):
            msg = f"sample values must fit {self.sample_bits} bits"
            raise PacketValueError(msg)
        length = MIN_PACKET_LEN + _FRAME_ROWS_HEAD.size + 2 * arr.size
        if length > MAX_PACKET_LEN:
            msg = f"packet of {length} bytes exceeds MAX_PACKET_LEN={MAX_PACKET_LEN}"
            raise PacketValueError(msg)
        if arr.dtype != np.uint16 or arr.flags.writeable:
            arr = arr.astype(np.uint16)  # a private copy, so the caller's array may change
            arr.flags.writeable = False
        object.__setattr__(self, "samples", arr)

    @property
    def row_count(self) -> int:
        return int(self.samples.shape[0])

    @property
    def geometry(self) -> tuple[int, int, int]:
        """(rows, cols, sample_bits) of the frame this block belongs to."""
        return (self.rows, self.cols, self.sample_bits)

    def to_bytes(self) -> bytes:
        head = _FRAME_ROWS_HEAD.pack(
            self.foot,
            self.seq,
            self.board_clock_us,
            self.rows,
            self.cols,
            self.sample_bits,
            self.row_start,
            self.row_count,
        )
        return _seal(TYPE_FRAME_ROWS, head + self.samples.astype("<u2").tobytes())

    @classmethod
    def from_bytes(cls, packet: bytes) -> FrameRows:
        """Parse one whole packet (version .. crc); raises a ``DecodeError``."""
        return _parse_as(packet, FrameRows, "FRAME_ROWS")

    @classmethod
    def from_raw(cls, raw: RawRows) -> FrameRows:
        """The block of a packet ``raw_rows`` accepted (checked: no checks again)."""
        foot, seq, clock, rows, cols, bits, row_start, row_count, packet = raw
        block = _new(cls)
        _set(block, "__dict__", {
            "foot": _FEET[foot], "seq": seq, "board_clock_us": clock, "rows": rows, "cols": cols,
            "sample_bits": bits, "row_start": row_start,
            "samples": np.ndarray((row_count, cols), _WIRE_SAMPLE, packet, SAMPLES_AT),
        })  # fmt: skip
        return block

    @classmethod
    def _from_packet(cls, packet: bytes) -> FrameRows:
        """The block in a whole packet whose CRC, version and type are checked."""
        size = len(packet) - MIN_PACKET_LEN  # the body's
        if size < _FRAME_ROWS_HEAD.size:
            msg = f"FRAME_ROWS body of {size} bytes, the header needs {_FRAME_ROWS_HEAD.size}"
            raise MalformedError(msg)
        foot, seq, clock, rows, cols, bits, row_start, row_count = _FRAME_ROWS_HEAD.unpack_from(
            packet, HEADER_LEN
        )
        expected = _FRAME_ROWS_HEAD.size + 2 * row_count * cols
        if size != expected:
            msg = f"FRAME_ROWS body of {size} bytes, {row_count}x{cols} samples need"
            msg += f" {expected}"
            raise MalformedError(msg)
        if foot > 1:
            msg = f"foot={foot} is neither 0 (left) nor 1 (right)"
            raise MalformedError(msg)
        samples = np.frombuffer(packet, _WIRE_SAMPLE, row_count * cols, SAMPLES_AT)
        samples = samples.reshape(row_count, cols) if cols else samples.reshape(row_count, 0)
        try:  # not the common case (``raw_rows``): the constructor's checks say what
            return cls(Foot(foot), seq, clock, rows, cols, bits, row_start, samples)
        except PacketValueError as exc:
            raise MalformedError(str(exc)) from None

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, FrameRows):
            return NotImplemented
        return self._key() == other._key() and np.array_equal(self.samples, other.samples)

    __hash__ = None  # type: ignore[assignment]  # holds an array: not hashable

    def _key(self) -> tuple[int, ...]:
        return (self.foot, self.seq, self.board_clock_us, *self.geometry, self.row_start)


@dataclass(frozen=True)
class InsoleStatus:
    """What the receiver knows about one insole's battery and radio link."""

    battery_mv: int | None = None  # battery voltage, None until the insole reported it
    battery_pct: int | None = None  # state of charge 0..100, None when unknown
    rssi_dbm: int | None = None  # signal strength of the last radio packet, None when unheard
    link_up: bool = False  # heard within the last second
    packets_lost: int = 0  # u32 radio packets missed (by the radio's own sequence), wraps

    def __post_init__(self) -> None:
        if self.battery_mv is not None:
            _check_range("battery_mv", self.battery_mv, 1, 0xFFFF)
        if self.battery_pct is not None:
            _check_range("battery_pct", self.battery_pct, 0, 100)
        if self.rssi_dbm is not None:
            _check_range("rssi_dbm", self.rssi_dbm, -127, 127)
        _check_range("packets_lost", self.packets_lost, 0, _U32)

    def _pack(self) -> bytes:
        return _INSOLE.pack(
            BATTERY_MV_UNKNOWN if self.battery_mv is None else self.battery_mv,
            BATTERY_PCT_UNKNOWN if self.battery_pct is None else self.battery_pct,
            RSSI_UNKNOWN if self.rssi_dbm is None else self.rssi_dbm,
            LINK_UP if self.link_up else 0,
            self.packets_lost,
        )

    @classmethod
    def _unpack(cls, body: bytes, offset: int) -> InsoleStatus:
        mv, pct, rssi, flags, lost = _INSOLE.unpack_from(body, offset)
        if pct != BATTERY_PCT_UNKNOWN and pct > 100:
            msg = f"battery_pct={pct} is neither 0..100 nor {BATTERY_PCT_UNKNOWN} (unknown)"
            raise MalformedError(msg)
        return cls(
            battery_mv=None if mv == BATTERY_MV_UNKNOWN else mv,
            battery_pct=None if pct == BATTERY_PCT_UNKNOWN else pct,
            rssi_dbm=None if rssi == RSSI_UNKNOWN else rssi,
            link_up=bool(flags & LINK_UP),  # other flag bits are reserved and ignored
            packets_lost=lost,
        )

    def as_dict(self) -> dict[str, Any]:
        return {
            "battery_mv": self.battery_mv,
            "battery_pct": self.battery_pct,
            "rssi_dbm": self.rssi_dbm,
            "link_up": self.link_up,
            "packets_lost": self.packets_lost,
        }


@dataclass(frozen=True)
class BoardStatus:
    """The receiver's periodic report (type 0x02), about once a second."""

    uptime_s: int = 0  # u32 seconds since the receiver booted
    rx_packets: int = 0  # u32 radio packets received with a good radio CRC, wraps
    radio_crc_errors: int = 0  # u32 radio packets dropped for a bad radio CRC, wraps
    overflows: int = 0  # u32 packets dropped because the USB send buffer was full, wraps
    left: InsoleStatus = InsoleStatus()
    right: InsoleStatus = InsoleStatus()

    def __post_init__(self) -> None:
        for name in ("uptime_s", "rx_packets", "radio_crc_errors", "overflows"):
            _check_range(name, getattr(self, name), 0, _U32)

    def insole(self, foot: Foot) -> InsoleStatus:
        return self.left if foot == Foot.LEFT else self.right

    def to_bytes(self) -> bytes:
        head = _STATUS_HEAD.pack(
            self.uptime_s, self.rx_packets, self.radio_crc_errors, self.overflows
        )
        return _seal(TYPE_BOARD_STATUS, head + self.left._pack() + self.right._pack())

    @classmethod
    def from_bytes(cls, packet: bytes) -> BoardStatus:
        """Parse one whole packet (version .. crc); raises a ``DecodeError``."""
        return _parse_as(packet, BoardStatus, "BOARD_STATUS")

    @classmethod
    def _from_body(cls, body: bytes) -> BoardStatus:
        if len(body) != BOARD_STATUS_BODY_LEN:
            msg = f"BOARD_STATUS body of {len(body)} bytes, expected {BOARD_STATUS_BODY_LEN}"
            raise MalformedError(msg)
        uptime, rx, crc_errors, overflows = _STATUS_HEAD.unpack_from(body)
        left = InsoleStatus._unpack(body, _STATUS_HEAD.size)
        right = InsoleStatus._unpack(body, _STATUS_HEAD.size + _INSOLE.size)
        return cls(uptime, rx, crc_errors, overflows, left, right)

    def as_dict(self) -> dict[str, Any]:
        return {
            "uptime_s": self.uptime_s,
            "rx_packets": self.rx_packets,
            "radio_crc_errors": self.radio_crc_errors,
            "overflows": self.overflows,
            "left": self.left.as_dict(),
            "right": self.right.as_dict(),
        }


Packet: TypeAlias = FrameRows | BoardStatus
_P = TypeVar("_P", FrameRows, BoardStatus)


def _parse_as(packet: bytes, kind: type[_P], name: str) -> _P:
    """``parse_packet``, and a ``MalformedError`` unless it is a ``kind`` packet."""
    result = parse_packet(packet)
    if not isinstance(result, kind):
        msg = f"expected {name}, got packet type {packet[1]:#04x}"
        raise MalformedError(msg)
    return result


# A FRAME_ROWS packet ``raw_rows`` found right, its header read:
# (foot, seq, board_clock_us, rows, cols, sample_bits, row_start, row_count, packet).
RawRows: TypeAlias = tuple[int, int, int, int, int, int, int, int, bytes]


def raw_rows(packet: bytes) -> RawRows | None:
    """A whole FRAME_ROWS packet (``bytes``) in the common case, header read; else None.

    The common case needs none of ``parse_packet``'s error paths: at most
    MAX_PACKET_LEN bytes, CRC, version and type right, the body as long as its
    header says, foot 0 or 1, rows, cols and row_count not 0, the rows inside the
    frame, 8..16-bit samples that fit. For anything else ``parse_packet`` says what.
    No numpy call and no object per packet: eight packets per frame pair.
    """
    size = len(packet)
    if size < SAMPLES_AT or size > MAX_PACKET_LEN or packet[0] != VERSION:
        return None
    foot, seq, clock, rows, cols, bits, row_start, row_count = _FRAME_ROWS_HEAD.unpack_from(
        packet, HEADER_LEN
    )
    if (
        packet[1] != TYPE_FRAME_ROWS
        or size != SAMPLES_AT + 2 * row_count * cols + CRC_LEN
        or foot > 1
        or not (rows and cols and row_count)
        or row_start + row_count > rows
        or not 8 <= bits <= MAX_SAMPLE_BITS
        or zlib.crc32(packet) != _CRC_RESIDUE
    ):
        return None
    if bits < MAX_SAMPLE_BITS and packet[SAMPLES_AT + 1 : -CRC_LEN : 2].translate(
        None, _HIGH_BYTES[bits]
    ):
        return None  # a sample over ``bits``
    return (foot, seq, clock, rows, cols, bits, row_start, row_count, packet)


def parse_packet(packet: bytes) -> Packet:
    """Check length, CRC, version and type of one decoded packet, then parse its body.

    Raises a ``DecodeError`` subclass naming why the packet is dropped.
    """
    size = len(packet)
    if size > MAX_PACKET_LEN:
        msg = f"packet of {size} bytes exceeds {MAX_PACKET_LEN}"
        raise TooLongError(msg)
    if size < MIN_PACKET_LEN:
        msg = f"packet of {size} bytes, the shortest is {MIN_PACKET_LEN}"
        raise MalformedError(msg)
    packet = bytes(packet)
    raw = raw_rows(packet)
    if raw is not None:
        return FrameRows.from_raw(raw)
    if zlib.crc32(packet) != _CRC_RESIDUE:
        sent = int.from_bytes(packet[-CRC_LEN:], "little")
        computed = crc32(packet[:-CRC_LEN])
        msg = f"crc32 {sent:#010x} sent, {computed:#010x} computed"
        raise BadCrcError(msg)
    version, packet_type = packet[0], packet[1]
    if version != VERSION:
        msg = f"protocol version {version}, this host speaks {VERSION}"
        raise BadVersionError(msg)
    if packet_type == TYPE_FRAME_ROWS:
        return FrameRows._from_packet(packet)
    if packet_type == TYPE_BOARD_STATUS:
        return BoardStatus._from_body(packet[HEADER_LEN:-CRC_LEN])
    msg = f"packet type {packet_type:#04x} is not known to this host"
    raise UnknownTypeError(msg, packet_type)


def try_parse_packet(packet: bytes) -> Packet | DecodeError:
    """``parse_packet`` that returns the error instead of raising it."""
    try:
        return parse_packet(packet)
    except DecodeError as exc:
        return exc


def frame_blocks(
    foot: Foot,
    seq: int,
    board_clock_us: int,
    counts: np.ndarray,
    rows_per_block: int = 8,
    sample_bits: int = DEFAULT_SAMPLE_BITS,
) -> list[FrameRows]:
    """Split one foot frame ``counts`` (rows, cols) into FRAME_ROWS blocks, top row first."""
    frame = np.asarray(counts)
    rows, cols = frame.shape
    return [
        FrameRows(foot, seq, board_clock_us, rows, cols, sample_bits, start, frame[start:stop])
        for start in range(0, rows, rows_per_block)
        for stop in (min(rows, start + rows_per_block),)
    ]
