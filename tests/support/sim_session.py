"""Reading simulated session files back for the simulator's tests."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scotti.firmware_protocol.assembly import FootFrame, FrameAssembler
from scotti.firmware_protocol.framing import DecoderCounters, StreamDecoder
from scotti.firmware_protocol.packets import BoardStatus, FrameRows
from scotti.firmware_protocol.session import Session, read_session


@dataclass
class Decoded:
    session: Session
    blocks: list[tuple[int, FrameRows]] = field(default_factory=list)  # (t_ns, block)
    statuses: list[tuple[int, BoardStatus]] = field(default_factory=list)
    frames: list[FootFrame] = field(default_factory=list)
    counters: DecoderCounters = field(default_factory=DecoderCounters)

    def frame_counts(self, frames: int) -> np.ndarray:
        """(frames, 2, rows, cols) counts of complete frames by seq (seq_start 0)."""
        out = np.full((frames, 2, 32, 22), -1, dtype=np.int64)
        for f in self.frames:
            if f.complete:
                out[f.seq, int(f.foot)] = f.counts
        return out


def decode_session(path: Path) -> Decoded:
    """Every record's bytes through StreamDecoder, FRAME_ROWS through FrameAssembler."""
    session = read_session(path)
    out = Decoded(session)
    decoder = StreamDecoder()
    assembler = FrameAssembler()
    for record in session.packets:
        for item in decoder.feed(record.data):
            if isinstance(item, FrameRows):
                out.blocks.append((record.t_ns, item))
                out.frames += assembler.push(item, record.t_ns)
            elif isinstance(item, BoardStatus):
                out.statuses.append((record.t_ns, item))
    out.frames += assembler.flush()
    out.counters = decoder.counters
    return out
