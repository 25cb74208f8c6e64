"""Row blocks -> foot frames: the host side of FRAME_ROWS (PROTOCOL.md, "Row blocks").

A frame is emitted as soon as all its rows are in. A frame still missing rows
is emitted, ``complete=False`` with its ``rows_missing`` marked, when a newer
frame of the same foot needs its slot, or on ``flush()``. Frames of one foot
come out in sequence order; a block for a frame already emitted (or older)
is dropped and counted, so a frame is never emitted twice.
"""

from __future__ import annotations

import sys
from collections import deque
from dataclasses import asdict, dataclass, field
from typing import Final

import numpy as np
from scotti.firmware_protocol.packets import (
    CRC_LEN,
    DEFAULT_SAMPLE_BITS,
    SAMPLES_AT,
    Foot,
    FrameRows,
    RawRows,
)
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


def _foot_frame(
    foot: Foot,
    seq: int,
    board_clock_us: int,
    counts: np.ndarray,
    rows_missing: np.ndarray,
    complete: bool,
    last_byte_ns: int,
    sample_bits: int,
) -> FootFrame:
    """``FootFrame(...)`` without the frozen dataclass's one ``object.__setattr__`` per
    field: two foot frames per moment."""
    frame = object.__new__(FootFrame)
    vars(frame).update(
        foot=foot,
        seq=seq,
        board_clock_us=board_clock_us,
        counts=counts,
        rows_missing=rows_missing,
        complete=complete,
        last_byte_ns=last_byte_ns,
        sample_bits=sample_bits,
    )
    return frame


# rows -> all False, read-only: the ``rows_missing`` of every whole frame assembled here
_NONE_MISSING: dict[int, np.ndarray] = {}
_NONE_MISSING_IDS: set[int] = set()  # theirs (they live as long as the module)


def _none_missing(rows: int) -> np.ndarray:
    missing = _NONE_MISSING.get(rows)
    if missing is None:
        missing = _NONE_MISSING[rows] = np.zeros(rows, dtype=bool)
        missing.flags.writeable = False
        _NONE_MISSING_IDS.add(id(missing))
    return missing


def no_rows_missing(frame: FootFrame) -> bool:
    """``not frame.rows_missing.any()``; no numpy call for a whole frame assembled here."""
    missing = frame.rows_missing
    return id(missing) in _NONE_MISSING_IDS or not missing.any()


# Blocks in row order are kept as they came and joined once, as little-endian u16 bytes.
_JOIN_IN_ORDER: Final = sys.byteorder == "little"
_FOOT: Final = (Foot.LEFT, Foot.RIGHT)  # by wire value
_WIRE_SAMPLE: Final = np.dtype("<u2")


def _joined(pieces: list[bytes | memoryview]) -> bytes:
    try:
        return b"".join(pieces)
    except TypeError:  # a FrameRows' samples not contiguous in memory
        return b"".join(p.tobytes() if isinstance(p, memoryview) else p for p in pieces)


class _Partial:
    """A frame in progress.

    While its blocks come in row order (as the radio sends them) they are only kept
    (``pieces``) and joined when the last is in: one copy, no per-row bookkeeping.
    The first block out of order lays what came so far into ``counts``/``missing``.
    """

    __slots__ = (
        "board_clock_us",
        "counts",
        "geometry",
        "last_byte_ns",
        "missing",
        "next_row",
        "pieces",
        "seq",
    )

    def __init__(self, seq: int, board_clock_us: int, geometry: tuple[int, int, int]) -> None:
        self.seq = seq
        self.board_clock_us = board_clock_us  # the first block's
        self.geometry = geometry
        self.last_byte_ns = 0
        # samples of rows 0..next_row-1, in order: the wire's bytes, or a FrameRows' memory
        self.pieces: list[bytes | memoryview] = []
        self.next_row = 0
        self.counts: np.ndarray | None = None  # (rows, cols), once a block came out of order
        self.missing: np.ndarray | None = None  # (rows,) True for a row not received yet

    @property
    def complete(self) -> bool:
        if self.missing is None:
            return self.next_row == self.geometry[0]
        return not self.missing.any()

    def add(self, block: FrameRows, t_ns: int) -> int:
        """Copy the block's rows in; returns how many of them were already there."""
        if t_ns > self.last_byte_ns:
            self.last_byte_ns = t_ns
        samples = block.samples
        if self.counts is None or self.missing is None:
            if block.row_start == self.next_row and _JOIN_IN_ORDER:
                self.pieces.append(samples.data)
                self.next_row += len(samples)
                return 0
            counts, missing = self._lay_out()
        else:
            counts, missing = self.counts, self.missing
        rows = slice(block.row_start, block.row_start + block.row_count)
        fresh = missing[rows]
        if fresh.all():  # rows not seen yet, copied whole
            counts[rows] = samples
            missing[rows] = False
            return 0
        fresh = fresh.copy()
        counts[rows][fresh] = samples[fresh]
        missing[rows] = False
        return int((~fresh).sum())

    def _lay_out(self) -> tuple[np.ndarray, np.ndarray]:
        """The rows kept so far into arrays (a block came out of order, or rows are missing)."""
        rows, cols, _ = self.geometry
        counts = self.counts = np.zeros((rows, cols), dtype=np.uint16)
        missing = self.missing = np.ones(rows, dtype=bool)
        if self.pieces:
            received = np.frombuffer(_joined(self.pieces), dtype=_WIRE_SAMPLE)
            counts[: self.next_row] = received.reshape(self.next_row, cols)
            missing[: self.next_row] = False
            self.pieces = []
        return counts, missing

    def finish(self, foot: Foot) -> FootFrame:
        rows, cols, bits = self.geometry
        if self.counts is None or self.missing is None:
            if self.next_row == rows:  # every block came, in order
                counts = np.frombuffer(_joined(self.pieces), dtype=_WIRE_SAMPLE)
                counts = counts.reshape(rows, cols)
                return _foot_frame(
                    foot, self.seq, self.board_clock_us, counts, _none_missing(rows), True,
                    self.last_byte_ns, bits,
                )  # fmt: skip
            counts, missing = self._lay_out()
        else:
            counts, missing = self.counts, self.missing
        counts.flags.writeable = False
        missing.flags.writeable = False
        return _foot_frame(
            foot, self.seq, self.board_clock_us, counts, missing, not missing.any(),
            self.last_byte_ns, bits,
        )  # fmt: skip


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

    def push_raw(self, raw: RawRows, t_ns: int = 0) -> list[FootFrame]:
        """``push(FrameRows.from_raw(raw), t_ns)``, the same frames and counts.

        A block that continues its foot's frame in row order, or starts a frame when
        none is in progress, is only kept as the bytes it came in: no array, no
        FrameRows. Anything else goes through ``push``.
        """
        foot, seq, _clock, rows, cols, bits, row_start, row_count, packet = raw
        state = self._feet[_FOOT[foot]]
        last = state.last_emitted
        # seq_delta(seq, last) > 0, inline: a block of a newer frame is not stale
        if _JOIN_IN_ORDER and (last is None or ((seq - last + 0x8000) & 0xFFFF) > 0x8000):
            pending = state.pending
            partial = pending.get(seq)
            if partial is None:
                if not pending and row_start == 0:
                    partial = pending[seq] = _Partial(seq, _clock, (rows, cols, bits))
            elif not (
                partial.missing is None
                and row_start == partial.next_row
                and partial.geometry == (rows, cols, bits)
            ):
                partial = None
            if partial is not None:
                self.counters.blocks += 1
                if t_ns > partial.last_byte_ns:
                    partial.last_byte_ns = t_ns
                partial.pieces.append(packet[SAMPLES_AT:-CRC_LEN])
                partial.next_row += row_count
                out: list[FootFrame] = []
                if partial.next_row == rows:
                    self._completed(state, _FOOT[foot], seq, out)
                return out
        return self.push(FrameRows.from_raw(raw), t_ns)

    def push(self, block: FrameRows, t_ns: int = 0) -> list[FootFrame]:
        """Add one block (``t_ns``: host monotonic time of its packet); return finished frames."""
        self.counters.blocks += 1
        state = self._feet[block.foot]
        out: list[FootFrame] = []
        last = state.last_emitted
        # seq_delta(block.seq, last) > 0, inline: a block of a newer frame is not stale
        fresh = last is None or ((block.seq - last + 0x8000) & 0xFFFF) > 0x8000
        if not fresh and self._stale(state, block, out):
            return out
        pending = state.pending
        partial = pending.get(block.seq)
        if partial is None:
            if len(pending) >= self.max_in_progress:
                while len(pending) >= self.max_in_progress:
                    self._emit(state, block.foot, self._oldest(state), out)
                if self._stale(state, block, out):  # the frames emitted moved last_emitted
                    return out
            partial = pending[block.seq] = _Partial(block.seq, block.board_clock_us, block.geometry)
        elif partial.geometry != block.geometry:
            self.counters.geometry_mismatches += 1
            return out
        self.counters.duplicate_rows += partial.add(block, t_ns)
        if partial.complete:
            self._completed(state, block.foot, block.seq, out)
        return out

    def _completed(self, state: _FootState, foot: Foot, seq: int, out: list[FootFrame]) -> None:
        """Frame ``seq`` has all its rows: out it goes, older incomplete ones first."""
        pending = state.pending
        if len(pending) == 1:  # the usual case: it is the only frame in progress
            self._emit(state, foot, seq, out)
            return
        for older in sorted(pending, key=lambda s: seq_delta(s, seq)):
            if seq_delta(older, seq) <= 0:
                self._emit(state, foot, older, out)

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
        last = state.last_emitted
        if last is None or ((seq - last + 0x8000) & 0xFFFF) > 0x8000:  # seq_delta(seq, last) > 0
            state.last_emitted = seq
        state.recent.append(seq)
        out.append(frame)
