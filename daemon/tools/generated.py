"""A receiver's bytes, generated: frame pairs of row-block packets with counting seqs and clocks.

What a board sends for frame ``i``: four FRAME_ROWS packets per foot (left,
then right), seq ``i`` mod 65536, board clocks ``i`` x 62.5 ms (u32 us, wrapping;
the right board's clock 7 ms apart), pressure from a small pool of random
frames. Packets are made from templates with the seq, clock and CRC written
in and COBS-encoded a batch at a time, so making the bytes costs a small part
of what the daemon spends on them (the day soak makes 1.38 million frames).
"""

from __future__ import annotations

import struct
from typing import Final

import numpy as np
from scotti.firmware_protocol import cobs
from scotti.firmware_protocol.packets import (
    CLOCK_MODULUS,
    CRC_LEN,
    SEQ_MODULUS,
    Foot,
    FrameRows,
    crc32,
)
from scotti.models.contract import FRAME_COLS, FRAME_RATE_HZ, FRAME_ROWS, MAX_COUNT, SAMPLE_BITS

PERIOD_NS: Final = round(1e9 / FRAME_RATE_HZ)
PERIOD_US: Final = PERIOD_NS // 1000
ROWS_PER_PACKET: Final = 8  # four radio packets per foot frame
BLOCKS_PER_FOOT: Final = FRAME_ROWS // ROWS_PER_PACKET
POOL: Final = 64  # distinct pressure frames per foot, cycled
_SEQ_CLOCK: Final = struct.Struct("<HI")  # seq and board clock inside a FRAME_ROWS packet
_SEQ_AT: Final = 3  # after [version:1] [type:1] [foot:1]


class GeneratedBoard:
    """``feet(first, count)``: the bytes of frame pairs ``first .. first+count-1``."""

    def __init__(self, seed: int = 0) -> None:
        rng = np.random.default_rng(seed)
        self._templates: list[list[bytes]] = []  # per pool frame: 8 packets, left then right
        for _ in range(POOL):
            packets = []
            for foot in (Foot.LEFT, Foot.RIGHT):
                counts = rng.integers(0, MAX_COUNT // 3, (FRAME_ROWS, FRAME_COLS), np.uint16)
                packets += [
                    FrameRows(
                        foot, 0, 0, FRAME_ROWS, FRAME_COLS, SAMPLE_BITS, start,
                        counts[start : start + ROWS_PER_PACKET],
                    ).to_bytes()
                    for start in range(0, FRAME_ROWS, ROWS_PER_PACKET)
                ]  # fmt: skip
            self._templates.append(packets)

    def feet(self, first: int, count: int) -> list[tuple[bytes, bytes]]:
        """Per frame pair: (left foot's four packets, right foot's), encoded as sent."""
        packets: list[bytes] = []
        for i in range(first, first + count):
            seq = i % SEQ_MODULUS
            for n, template in enumerate(self._templates[i % POOL]):
                foot = n // BLOCKS_PER_FOOT
                clock = (1_000_000 + i * PERIOD_US + 7_000 * foot) % CLOCK_MODULUS
                packet = bytearray(template)
                _SEQ_CLOCK.pack_into(packet, _SEQ_AT, seq, clock)
                packet[-CRC_LEN:] = crc32(bytes(packet[:-CRC_LEN])).to_bytes(CRC_LEN, "little")
                packets.append(bytes(packet))
        encoded = [p + b"\x00" for p in cobs.encode_batch(packets)]
        per = 2 * BLOCKS_PER_FOOT
        return [
            (
                b"".join(encoded[k * per : k * per + BLOCKS_PER_FOOT]),
                b"".join(encoded[k * per + BLOCKS_PER_FOOT : (k + 1) * per]),
            )
            for k in range(count)
        ]

    def chunks(self, first: int, count: int) -> list[bytes]:
        """Per frame pair: all eight packets as one read."""
        return [left + right for left, right in self.feet(first, count)]

    def records(self, frames: int, gap_ns: int = 2_000_000) -> list[tuple[int, bytes]]:
        """``frames`` frame pairs as session-style records: each foot's packets at its time."""
        out: list[tuple[int, bytes]] = []
        for first in range(0, frames, 256):
            for k, (left, right) in enumerate(self.feet(first, min(256, frames - first))):
                t = (first + k) * PERIOD_NS
                out += [(t, left), (t + gap_ns, right)]
        return out
