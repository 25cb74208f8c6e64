"""Row blocks -> foot frames: the host side of FRAME_ROWS (PROTOCOL.md, "Row blocks").

A frame is emitted as soon as all its rows are in. A frame still missing rows
is emitted, ``complete=False`` with its ``rows_missing`` marked, when a newer
frame of the same foot needs its slot, or on ``flush()``. Frames of one foot
come out in sequence order; a block for a frame already emitted (or older)
is dropped and counted, so a frame is never emitted twice.
"""

from __future__ import annotations

from collections import deque
from dataclasses import asdict, dataclass, field
from typing import Final

import numpy as np
from scotti.firmware_protocol.packets import DEFAULT_SAMPLE_BITS, Foot, FrameRows
from scotti.firmware_protocol.wrap import seq_delta

# A block this many frames (or more) behind the newest emitted one means the
# insole restarted its sequence, not a late packet (64 frames = 4 s at 16 Hz).
RESTART_GAP: Final = 64
RECENT_SEQS: Final = 16  # emitted seqs remembered per foot to tell duplicates from late blocks


@dataclass(frozen=True, eq=False)
class FootFrame:
    """One foot's whole frame, possibly with rows missing (zero-filled)."""

    foot: Foot
    seq: int  # u16 frame sequence number from the insole
    board_clock_us: int  # u32 insole clock of the frame (from its first block)
    counts: np.ndarray = field(repr=False)  # (rows, cols) uint16, read-only, 0 where missing
    rows_missing: np.ndarray = field(repr=False)  # (rows,) bool, True for a row never received
    complete: bool = True
    last_byte_ns: int = 0  # host monotonic ns of the last block that contributed; 0 if unknown
    sample_bits: int = DEFAULT_SAMPLE_BITS

    @property
    def rows(self) -> int:
        return int(self.counts.shape[0])

    @property
    def cols(self) -> int:
        return int(self.counts.shape[1])

    @property
    def missing_count(self) -> int:
        return int(self.rows_missing.sum())

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, FootFrame):
            return NotImplemented
        mine = (self.foot, self.seq, self.board_clock_us, self.complete, self.last_byte_ns)
        theirs = (other.foot, other.seq, other.board_clock_us, other.complete, other.last_byte_ns)
        return (
            mine == theirs
            and self.sample_bits == other.sample_bits
            and np.array_equal(self.counts, other.counts)
            and np.array_equal(self.rows_missing, other.rows_missing)
        )

    __hash__ = None  # type: ignore[assignment]  # holds arrays: not hashable


@dataclass
class AssemblerCounters:
    """What a ``FrameAssembler`` has done since it was made (all only grow)."""

    blocks: int = 0  # FRAME_ROWS blocks pushed
    frames_complete: int = 0  # frames emitted with every row
    frames_incomplete: int = 0  # frames emitted with rows missing
    rows_missing: int = 0  # rows missing in all incomplete frames together
    duplicate_blocks: int = 0  # blocks of a frame already emitted (dropped)
    late_blocks: int = 0  # blocks older than the newest emitted frame, never emitted (dropped)
    duplicate_rows: int = 0  # rows received twice for a frame in progress (first kept)
    geometry_mismatches: int = 0  # blocks whose geometry disagrees with their frame (dropped)
    geometry_changes: int = 0  # emitted frames whose geometry differs from the foot's previous
    restarts: int = 0  # sequence jumped back >= RESTART_GAP: the insole restarted

    def as_dict(self) -> dict[str, int]:
        return asdict(self)


class _Partial:
    """A frame in progress."""

    def __init__(self, block: FrameRows) -> None:
        self.seq = block.seq
        self.board_clock_us = block.board_clock_us
        self.geometry = block.geometry
        self.counts = np.zeros((block.rows, block.cols), dtype=np.uint16)
        self.missing = np.ones(block.rows, dtype=bool)
        self.last_byte_ns = 0

    def add(self, block: FrameRows, t_ns: int) -> int:
        """Copy the block's rows in; returns how many of them were already there."""
        rows = slice(block.row_start, block.row_start + block.row_count)
        self.last_byte_ns = max(self.last_byte_ns, t_ns)
        fresh = self.missing[rows]
        if fresh.all():  # the common case: rows not seen yet, copied whole
            self.counts[rows] = block.samples
            self.missing[rows] = False
            return 0
        fresh = fresh.copy()
        self.counts[rows][fresh] = block.samples[fresh]
        self.missing[rows] = False
        return int((~fresh).sum())

    def finish(self, foot: Foot) -> FootFrame:
        self.counts.flags.writeable = False
        self.missing.flags.writeable = False
        return FootFrame(
            foot=foot,
            seq=self.seq,
            board_clock_us=self.board_clock_us,
            counts=self.counts,
            rows_missing=self.missing,
            complete=not self.missing.any(),
            last_byte_ns=self.last_byte_ns,
            sample_bits=self.geometry[2],
        )


class _FootState:
    def __init__(self) -> None:
        self.pending: dict[int, _Partial] = {}  # seq -> frame in progress
        self.last_emitted: int | None = None
        self.recent: deque[int] = deque(maxlen=RECENT_SEQS)
        self.last_geometry: tuple[int, int, int] | None = None


class FrameAssembler:
    """Assembles FRAME_ROWS blocks into ``FootFrame`` values, per foot.

    ``max_in_progress`` bounds the frames held per foot; 1 (the default)
    emits a frame with missing rows as soon as a block of a newer frame
    arrives, which is right for a receiver that forwards blocks in order.
    """

    def __init__(self, max_in_progress: int = 1) -> None:
        if max_in_progress < 1:
            msg = "max_in_progress must be at least 1"
            raise ValueError(msg)
        self.max_in_progress = max_in_progress
        self.counters = AssemblerCounters()
        self._feet = {foot: _FootState() for foot in Foot}

    @property
    def in_progress(self) -> int:
        """Frames held for both feet together."""
        return sum(len(state.pending) for state in self._feet.values())

    def push(self, block: FrameRows, t_ns: int = 0) -> list[FootFrame]:
        """Add one block (``t_ns``: host monotonic time of its packet); return finished frames."""
        self.counters.blocks += 1
        state = self._feet[block.foot]
        out: list[FootFrame] = []
        if self._stale(state, block, out):
            return out
        partial = state.pending.get(block.seq)
        if partial is None:
            while len(state.pending) >= self.max_in_progress:
                self._emit(state, block.foot, self._oldest(state), out)
            if self._stale(state, block, out):
                return out
            partial = state.pending[block.seq] = _Partial(block)
        elif partial.geometry != block.geometry:
            self.counters.geometry_mismatches += 1
            return out
        self.counters.duplicate_rows += partial.add(block, t_ns)
        if not partial.missing.any():
            for seq in sorted(state.pending, key=lambda s: seq_delta(s, block.seq)):
                if seq_delta(seq, block.seq) <= 0:
                    self._emit(state, block.foot, seq, out)  # older incomplete ones first
        return out

    def flush(self) -> list[FootFrame]:
        """Emit every frame in progress (the stream ended or was cut), oldest first."""
        out: list[FootFrame] = []
        for foot, state in self._feet.items():
            while state.pending:
                self._emit(state, foot, self._oldest(state), out)
        return out

    def _stale(self, state: _FootState, block: FrameRows, out: list[FootFrame]) -> bool:
        """Count and drop a block of an emitted or older frame; notice a restart."""
        if state.last_emitted is None:
            return False
        behind = seq_delta(block.seq, state.last_emitted)
        if behind > 0:
            return False
        if behind <= -RESTART_GAP:
            self.counters.restarts += 1
            while state.pending:
                self._emit(state, block.foot, self._oldest(state), out)
            state.last_emitted = None
            state.recent.clear()
            return False
        if block.seq in state.recent:
            self.counters.duplicate_blocks += 1
        else:
            self.counters.late_blocks += 1
        return True

    @staticmethod
    def _oldest(state: _FootState) -> int:
        anchor = next(iter(state.pending))
        return min(state.pending, key=lambda seq: seq_delta(seq, anchor))

    def _emit(self, state: _FootState, foot: Foot, seq: int, out: list[FootFrame]) -> None:
        partial = state.pending.pop(seq)
        frame = partial.finish(foot)
        counters = self.counters
        if frame.complete:
            counters.frames_complete += 1
        else:
            counters.frames_incomplete += 1
            counters.rows_missing += frame.missing_count
        if state.last_geometry is not None and state.last_geometry != partial.geometry:
            counters.geometry_changes += 1
        state.last_geometry = partial.geometry
        if state.last_emitted is None or seq_delta(seq, state.last_emitted) > 0:
            state.last_emitted = seq
        state.recent.append(seq)
        out.append(frame)
