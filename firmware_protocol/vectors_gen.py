"""Known-answer vectors for the wire protocol: ``python -m scotti.firmware_protocol.vectors_gen``.

Writes ``vectors/*.hex`` (or with ``--check`` only compares them and exits 1
on a difference). Each file: ``#`` comment lines (what it holds, then
``# expect:`` lines of ``field=value`` the decoded packets must show), then the
wire bytes (COBS packets, each ending in 00) as spaced hex, 16 bytes a line.
The firmware's tests read the same files.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scotti.firmware_protocol import cobs
from scotti.firmware_protocol.framing import encode_packet
from scotti.firmware_protocol.packets import (
    BoardStatus,
    Foot,
    FrameRows,
    InsoleStatus,
    Packet,
    crc32,
    frame_blocks,
)

VECTORS_DIR = Path(__file__).parent / "vectors"
_SAMPLE_RULE = "sample[r][c] = (r * 22 + c) * 37 mod 4096, r the row in the whole frame"


@dataclass(frozen=True)
class Vector:
    name: str
    about: tuple[str, ...]  # comment lines saying what the file holds
    expect: tuple[str, ...]  # "field=value ..." lines the decoded result must show
    wire: bytes

    def render(self) -> str:
        lines = [f"# {self.name}.hex: {self.about[0]}"]
        lines += [f"# {line}" for line in self.about[1:]]
        lines += [f"# expect: {line}" for line in self.expect]
        lines.append(f"# wire: {len(self.wire)} bytes")
        for start in range(0, len(self.wire), 16):
            lines.append(self.wire[start : start + 16].hex(" "))
        return "\n".join(lines) + "\n"


def pattern(rows: int = 32, cols: int = 22) -> np.ndarray:
    """The sample rule of the frame vectors, as a (rows, cols) array."""
    index = np.arange(rows * cols, dtype=np.int64).reshape(rows, cols)
    return ((index * 37) % 4096).astype(np.uint16)


def _packet_lines(packet: Packet) -> tuple[str, ...]:
    raw = packet.to_bytes()
    return (
        f"packet: {len(raw)} bytes before COBS, crc32 {crc32(raw[:-4]):#010x}"
        f" (sent as {raw[-4:].hex(' ')})",
    )


def _frame_expect(block: FrameRows) -> tuple[str, ...]:
    last = block.row_count - 1, block.cols - 1
    return (
        f"type=0x01 foot={int(block.foot)} seq={block.seq} board_clock_us={block.board_clock_us}",
        f"rows={block.rows} cols={block.cols} sample_bits={block.sample_bits}"
        f" row_start={block.row_start} row_count={block.row_count}",
        f"samples[0,0]={block.samples[0, 0]} samples[{last[0]},{last[1]}]={block.samples[last]}"
        f" samples_sum={int(block.samples.sum(dtype=np.int64))}",
    )


def tiny_frame() -> FrameRows:
    return FrameRows(Foot.LEFT, 0x0102, 0x03040506, 2, 2, 12, 1, np.array([[0x123, 0xABC]]))


def full_frame() -> FrameRows:
    return FrameRows(Foot.LEFT, 1, 1_000_000, 32, 22, 12, 0, pattern())


def row_block() -> FrameRows:
    return FrameRows(Foot.RIGHT, 65535, 4_294_967_000, 32, 22, 12, 24, pattern()[24:32])


def board_status() -> BoardStatus:
    return BoardStatus(
        uptime_s=3600,
        rx_packets=1000,
        radio_crc_errors=2,
        overflows=1,
        left=InsoleStatus(3700, battery_pct=64, rssi_dbm=-58, link_up=True, packets_lost=5),
        right=InsoleStatus(),
    )


def _status_expect(status: BoardStatus) -> tuple[str, ...]:
    head = " ".join(f"{k}={v}" for k, v in status.as_dict().items() if k not in ("left", "right"))
    feet = [
        " ".join(f"{side}.{k}={v}" for k, v in status.insole(foot).as_dict().items())
        for side, foot in (("left", Foot.LEFT), ("right", Foot.RIGHT))
    ]
    return ("type=0x02 " + head, *feet)


def _sealed(raw: bytes) -> bytes:
    """COBS + delimiter around a raw packet whose CRC is made right."""
    body = raw[:-4] if len(raw) > 4 else raw
    return cobs.encode(body + crc32(body).to_bytes(4, "little")) + b"\x00"


def stream() -> tuple[bytes, tuple[str, ...]]:
    """A stream with every kind of trouble a host must count and survive."""
    left = frame_blocks(Foot.LEFT, 2, 1_062_500, pattern(), rows_per_block=8)
    right_whole = FrameRows(Foot.RIGHT, 2, 1_062_480, 32, 22, 12, 0, pattern())
    flipped = bytearray(encode_packet(row_block()))
    flipped[40] ^= 0x01  # one bit flipped by noise: the CRC catches it
    status_wire = encode_packet(board_status())
    parts = [
        bytes.fromhex("13 37 be ef 00"),  # tail of a packet sent before the port opened
        *(encode_packet(block) for block in left),
        bytes.fromhex("00 00"),  # idle padding: ignored, not an error
        bytes(flipped),
        _sealed(b"\x01\x80vendor debug" + bytes(4)),  # unknown type 0x80: counted, skipped
        _sealed(b"\x02\x01" + bytes(8)),  # protocol version 2: counted, skipped
        status_wire,
        b"\x55" * 2100 + b"\x00",  # 2100 bytes without a delimiter: too long, dropped
        encode_packet(right_whole),
        status_wire[:10],  # a packet still arriving when the vector ends
    ]
    wire = b"".join(parts)
    expect = (
        "items=bad_cobs,frame_rows,frame_rows,frame_rows,frame_rows,bad_crc,unknown_type,"
        "bad_version,board_status,too_long,frame_rows",
        "packets=6 bad_cobs=1 bad_crc=1 unknown_type=1 bad_version=1 too_long=1 malformed=0"
        f" bytes_in={len(wire)} pending=10",
    )
    return wire, expect


def build() -> list[Vector]:
    stream_wire, stream_expect = stream()
    tiny, full, block, status = tiny_frame(), full_frame(), row_block(), board_status()
    return [
        Vector(
            "frame_rows_tiny",
            (
                "the worked example of PROTOCOL.md: a 2 x 2 frame, row 1 only",
                *_packet_lines(tiny),
            ),
            _frame_expect(tiny),
            encode_packet(tiny),
        ),
        Vector(
            "frame_rows_left_full",
            (
                "one whole left-foot frame (32 x 22, 12-bit) in one FRAME_ROWS packet",
                _SAMPLE_RULE,
                *_packet_lines(full),
            ),
            _frame_expect(full),
            encode_packet(full),
        ),
        Vector(
            "frame_rows_block",
            (
                "rows 24..31 of a right-foot frame at the seq and clock wrap edges",
                _SAMPLE_RULE,
                *_packet_lines(block),
            ),
            _frame_expect(block),
            encode_packet(block),
        ),
        Vector(
            "board_status",
            (
                "BOARD_STATUS: left insole linked, right insole never heard (unknowns)",
                *_packet_lines(status),
            ),
            _status_expect(status),
            encode_packet(status),
        ),
        Vector(
            "stream_with_garbage",
            (
                "a byte stream with garbage, padding, a flipped bit, an unknown type,",
                "a future version, an over-long run and a cut-off packet among good packets.",
                "Good packets: left seq 2 (board_clock_us 1062500) in four 8-row blocks,",
                "a status as in board_status.hex, right seq 2 (board_clock_us 1062480) whole;",
                _SAMPLE_RULE,
            ),
            stream_expect,
            stream_wire,
        ),
    ]


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--check", action="store_true", help="compare only; exit 1 on a change")
    parser.add_argument("--dir", type=Path, default=VECTORS_DIR, help="where the .hex files live")
    args = parser.parse_args(argv)
    stale = []
    for vector in build():
        path = args.dir / f"{vector.name}.hex"
        text = vector.render()
        if path.exists() and path.read_text() == text:
            continue
        stale.append(path.name)
        if not args.check:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(text)
    verb = "differ" if args.check else "rewritten"
    print(f"{len(stale)} vector file(s) {verb}: {', '.join(stale) or '-'}")
    return 1 if args.check and stale else 0


if __name__ == "__main__":
    sys.exit(main())
