"""Bytes to paired frames: the one frame path, sans-I/O.

    bytes --StreamDecoder--> packets --FrameAssembler--> foot frames --Pairing--> pairs

with the one set of repair rules (``pairing``: rows taken from the foot's
previous frame, a silent foot held then zero-filled, short gaps bridged,
long gaps and board restarts starting the window over, seqs unwrapped).

The daemon's pipeline, ``scotti eval``, training data (export/data.py),
``scotti session info`` and ``scotti sim render`` all go this way, so what
training learns from is exactly what the daemon serves
(tests/test_frame_path_parity.py holds that, byte for byte).

A caller that wants to see the packets and foot frames on the way (session
summaries count them) passes a ``FrameWatch``.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Iterator

from scotti.firmware_protocol.assembly import FootFrame, FrameAssembler
from scotti.firmware_protocol.errors import DecodeError
from scotti.firmware_protocol.framing import StreamDecoder
from scotti.firmware_protocol.packets import BoardStatus, FrameRows
from scotti.firmware_protocol.pairing import PairedFrame, Pairing, PairingConfig
from scotti.firmware_protocol.wrap import seq_delta

log = logging.getLogger(__name__)


class FrameWatch:
    """What passes along the path, for a caller that counts it (here: nothing)."""

    def block(self, block: FrameRows) -> None:
        """A decoded row block, before assembly."""

    def status(self, status: BoardStatus) -> None:
        """A decoded board status packet."""

    def frame(self, frame: FootFrame) -> None:
        """An assembled foot frame, before pairing."""


class FramePath:
    """``feed(bytes, t_ns) -> [PairedFrame]``; ``end()`` when the stream ends or is cut,
    ``reset()`` before a new connection. The stages' counters stay readable
    (``decoder.counters``, ``assembler.counters``, ``pairing.counters``)."""

    def __init__(
        self, pairing: PairingConfig | None = None, watch: FrameWatch | None = None
    ) -> None:
        self.decoder = StreamDecoder()
        self.assembler = FrameAssembler()
        self.pairing = Pairing(pairing)
        self.watch = watch if watch is not None else FrameWatch()
        self.board_status = 0  # status packets decoded

    def feed(self, data: bytes, t_ns: int) -> list[PairedFrame]:
        """The bytes of one read (``t_ns``: host monotonic time it arrived)."""
        out: list[PairedFrame] = []
        watch = self.watch
        # A watch that does not look at blocks or frames is not called for them (the
        # daemon's counts status packets only): two calls fewer per block.
        see_blocks = type(watch).block is not FrameWatch.block
        see_frames = type(watch).frame is not FrameWatch.frame
        assembler, push_frame = self.assembler, self.pairing.push
        for item in self.decoder.feed_raw(data):
            if isinstance(item, tuple) and not see_blocks:  # a FRAME_ROWS block, as it came
                frames = assembler.push_raw(item, t_ns)
            else:
                packet = FrameRows.from_raw(item) if isinstance(item, tuple) else item
                if isinstance(packet, FrameRows):
                    watch.block(packet)
                    frames = assembler.push(packet, t_ns)
                else:
                    if isinstance(packet, BoardStatus):
                        self.board_status += 1
                        watch.status(packet)
                    elif isinstance(packet, DecodeError):
                        log.debug("bad packet: %s", packet)
                    continue
            for frame in frames:
                if see_frames:
                    watch.frame(frame)
                out += push_frame(frame)
        return out

    def end(self) -> list[PairedFrame]:
        """The stream ended or was cut: frames still missing rows, then pairs still
        waiting for a foot, go out (the missing foot held or filled)."""
        out: list[PairedFrame] = []
        for frame in self.assembler.flush():
            self.watch.frame(frame)
            out += self.pairing.push(frame)
        return out + self.pairing.flush()

    def reset(self) -> None:
        """A new connection: partial packets are dropped, offsets learned again, and
        the next pair restarts the window (call ``end`` first to keep what came)."""
        self.decoder.reset()
        self.pairing.reset()


def stream_pairs(
    chunks: Iterable[tuple[int, bytes]], path: FramePath | None = None
) -> Iterator[PairedFrame]:
    """Every pair of a whole stream of ``(t_ns, bytes)`` reads (a session file's
    packet records), ended as a replay ends."""
    path = path if path is not None else FramePath()
    for t_ns, data in chunks:
        yield from path.feed(data, t_ns)
    yield from path.end()


class PairSeq:
    """Unwraps the u16 seq of successive pairs onto one axis (``ext``), as labels are.

    A pair's seq is its left foot's (held or expected included), the right's
    where the left was never heard; ``None`` for a pair with neither."""

    def __init__(self) -> None:
        self._raw: int | None = None
        self._ext = 0

    def of(self, pair: PairedFrame) -> int | None:
        seq = pair.seqs[0] if pair.seqs[0] >= 0 else pair.seqs[1]
        if seq < 0:
            return None
        if self._raw is None:
            self._ext = seq
        else:
            self._ext += seq_delta(seq, self._raw)
        self._raw = seq
        return self._ext
