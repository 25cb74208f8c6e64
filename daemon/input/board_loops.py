"""A session played again and again as one long session: the board's numbers go on.

A looping board emulator (the simulated source's, ``--simulate``) plays the same
packet records each time round. Sent as recorded, the insoles' frame sequence
numbers and clocks would jump back at every loop, as after an insole restart:
the window would start over, and a recording of it would read as many short
sessions (``scotti session info`` counts the restarts). So from the second time
round each packet is rewritten before it is sent: a FRAME_ROWS packet's
``seq`` moves on by the frames of one loop (mod 2**16) and its board clock by
the microseconds of one loop (mod 2**32), a BOARD_STATUS packet's uptime by the
seconds of one loop; the CRC is computed again and the packet COBS-framed
again. Bytes that are no whole packet with a good CRC (the scene's line noise,
a packet cut short) go out as they are.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

from scotti.firmware_protocol import cobs
from scotti.firmware_protocol.errors import BadCobsError
from scotti.firmware_protocol.framing import StreamDecoder
from scotti.firmware_protocol.packets import (
    CLOCK_MODULUS,
    CRC_LEN,
    MIN_PACKET_LEN,
    SEQ_MODULUS,
    TYPE_BOARD_STATUS,
    TYPE_FRAME_ROWS,
    VERSION,
    FrameRows,
)
from scotti.firmware_protocol.wrap import clock_delta_us, seq_delta

# Offsets in a packet (before COBS): [version:1] [type:1] then the body.
_SEQ_AT: Final = 3  # FRAME_ROWS: after version, type and foot
_CLOCK_AT: Final = 5
_UPTIME_AT: Final = 2  # BOARD_STATUS: the body's first field
_U16: Final = struct.Struct("<H")
_U32: Final = struct.Struct("<I")


@dataclass(frozen=True)
class LoopSteps:
    """How far the board's numbers move on in one loop."""

    seq: int  # frames: the next loop's first frame follows the last one
    clock_us: int  # board clock microseconds
    uptime_s: int  # the receiver's uptime, whole seconds


def loop_steps(records: Sequence[tuple[int, bytes]], loop_ns: int) -> LoopSteps | None:
    """The steps of a session's packet records played in a loop every ``loop_ns`` (host
    time); None when they hold no frame (nothing to rewrite)."""
    decoder = StreamDecoder()
    # Per foot: the last (seq, clock) seen, how far the stream is past its first frame
    # now (frames, clock us: unwrapped) and the farthest it went (late packets step back).
    last: dict[int, tuple[int, int]] = {}
    now: dict[int, tuple[int, int]] = {}
    reach: dict[int, tuple[int, int]] = {}
    for _, data in records:
        for item in decoder.feed(data):
            if not isinstance(item, FrameRows):
                continue
            foot = int(item.foot)
            if foot in last:
                seq, clock = last[foot]
                frames, clock_us = now[foot]
                now[foot] = (
                    frames + seq_delta(item.seq, seq),
                    clock_us + clock_delta_us(item.board_clock_us, clock),
                )
            else:
                now[foot] = reach[foot] = (0, 0)
            last[foot] = (item.seq, item.board_clock_us)
            reach[foot] = max(reach[foot], now[foot])
    if not reach:
        return None
    frames, clock_us = max(reach.values())
    span = frames + 1  # frames 0..frames of one loop
    per_frame_us = clock_us / frames if frames else loop_ns / 1e3
    return LoopSteps(
        seq=span % SEQ_MODULUS,
        clock_us=round(per_frame_us * span) % CLOCK_MODULUS,
        uptime_s=max(1, round(loop_ns / 1e9)),
    )


class LoopRewriter:
    """Rewrites the bytes of loop ``loop`` (0: the first, sent as recorded).

    Bytes are handed on packet by packet: a packet cut across two records goes out
    with the record that ends it (a few bytes later, never changed in order).
    """

    def __init__(self, steps: LoopSteps) -> None:
        self.steps = steps
        self.loop = 0
        self._carry = b""  # bytes after the last delimiter, waiting for the rest

    def rewrite(self, data: bytes) -> bytes:
        if self.loop == 0 and not self._carry:
            return data
        *frames, self._carry = (self._carry + data).split(b"\x00")
        return b"".join(self._packet(frame) + b"\x00" for frame in frames)

    def _packet(self, frame: bytes) -> bytes:
        if not frame or self.loop == 0:
            return frame
        try:
            packet = bytearray(cobs.decode(frame))
        except BadCobsError:
            return frame
        if len(packet) < MIN_PACKET_LEN or packet[0] != VERSION:
            return frame
        body_end = len(packet) - CRC_LEN
        if zlib.crc32(packet[:body_end]) != _U32.unpack_from(packet, body_end)[0]:
            return frame  # corrupt on the line: it stays corrupt
        k, steps = self.loop, self.steps
        if packet[1] == TYPE_FRAME_ROWS and body_end >= _CLOCK_AT + _U32.size:
            seq = (_U16.unpack_from(packet, _SEQ_AT)[0] + k * steps.seq) % SEQ_MODULUS
            clock = (_U32.unpack_from(packet, _CLOCK_AT)[0] + k * steps.clock_us) % CLOCK_MODULUS
            _U16.pack_into(packet, _SEQ_AT, seq)
            _U32.pack_into(packet, _CLOCK_AT, clock)
        elif packet[1] == TYPE_BOARD_STATUS and body_end >= _UPTIME_AT + _U32.size:
            uptime = (_U32.unpack_from(packet, _UPTIME_AT)[0] + k * steps.uptime_s) % (1 << 32)
            _U32.pack_into(packet, _UPTIME_AT, uptime)
        else:
            return frame
        _U32.pack_into(packet, body_end, zlib.crc32(packet[:body_end]))
        return cobs.encode(bytes(packet))
