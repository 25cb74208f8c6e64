"""Frame assembly: whole frames, row blocks, missing rows, duplicates, wraps, restarts."""

from __future__ import annotations

import numpy as np
import pytest
from scotti.firmware_protocol.assembly import FootFrame, FrameAssembler
from scotti.firmware_protocol.packets import Foot, FrameRows, frame_blocks

from tests.support.protocol import pattern_frame


def blocks(seq: int, foot: Foot = Foot.LEFT, per_block: int = 8) -> list[FrameRows]:
    return frame_blocks(foot, seq, seq * 62_500, pattern_frame(salt=seq), per_block)


def push_all(assembler: FrameAssembler, items: list[FrameRows], t0: int = 0) -> list[FootFrame]:
    return [frame for i, b in enumerate(items) for frame in assembler.push(b, t0 + i)]


def test_whole_frame_in_one_block() -> None:
    assembler = FrameAssembler()
    (frame,) = assembler.push(blocks(3, per_block=32)[0], t_ns=123)
    assert frame.complete
    assert (frame.foot, frame.seq, frame.board_clock_us, frame.last_byte_ns) == (
        Foot.LEFT,
        3,
        187_500,
        123,
    )
    assert frame.counts.dtype == np.uint16
    assert np.array_equal(frame.counts, pattern_frame(salt=3))
    assert not frame.rows_missing.any()
    assert not frame.counts.flags.writeable


def test_four_blocks_make_one_frame_when_the_last_arrives() -> None:
    assembler = FrameAssembler()
    parts = blocks(1)
    assert push_all(assembler, parts[:3]) == []
    assert assembler.in_progress == 1
    (frame,) = assembler.push(parts[3], t_ns=99)
    assert frame.complete
    assert frame.last_byte_ns == 99
    assert np.array_equal(frame.counts, pattern_frame(salt=1))
    assert assembler.counters.frames_complete == 1


def test_blocks_in_any_order_and_feet_interleaved() -> None:
    assembler = FrameAssembler()
    left, right = blocks(5), blocks(5, Foot.RIGHT)
    order = [left[2], right[3], left[0], right[0], left[3], right[1], left[1], right[2]]
    frames = push_all(assembler, order)
    assert [(f.foot, f.seq, f.complete) for f in frames] == [
        (Foot.LEFT, 5, True),
        (Foot.RIGHT, 5, True),
    ]


def test_missing_rows_are_marked_when_a_newer_frame_starts() -> None:
    assembler = FrameAssembler()
    first = blocks(10)
    frames = push_all(assembler, [first[0], first[1], first[3]])  # rows 16..23 lost
    assert frames == []
    (late,) = assembler.push(blocks(11)[0])
    assert not late.complete
    assert late.seq == 10
    assert late.rows_missing.tolist() == [False] * 16 + [True] * 8 + [False] * 8
    assert not late.counts[16:24].any()
    assert np.array_equal(late.counts[24:], pattern_frame(salt=10)[24:])
    assert (assembler.counters.frames_incomplete, assembler.counters.rows_missing) == (1, 8)


def test_flush_emits_what_is_in_progress() -> None:
    assembler = FrameAssembler()
    push_all(assembler, [blocks(1)[0], blocks(1, Foot.RIGHT)[1]])
    frames = assembler.flush()
    assert [(f.foot, f.missing_count) for f in frames] == [(Foot.LEFT, 24), (Foot.RIGHT, 24)]
    assert assembler.flush() == []


def test_duplicates_of_an_emitted_frame_are_dropped_and_counted() -> None:
    assembler = FrameAssembler()
    push_all(assembler, blocks(1) + blocks(2))
    assert push_all(assembler, blocks(2)[:2] + blocks(1)[:1]) == []
    assert assembler.counters.duplicate_blocks == 3
    assert assembler.counters.frames_complete == 2


def test_late_block_of_a_skipped_frame_is_dropped() -> None:
    assembler = FrameAssembler()
    push_all(assembler, blocks(4))
    assert assembler.push(blocks(3)[0]) == []
    assert assembler.counters.late_blocks == 1


def test_duplicate_rows_within_a_frame_keep_the_first() -> None:
    assembler = FrameAssembler()
    parts = blocks(1)
    other = FrameRows(Foot.LEFT, 1, 62_500, 32, 22, 12, 0, np.full((8, 22), 7, np.uint16))
    frames = push_all(assembler, [parts[0], other, *parts[1:]])
    assert np.array_equal(frames[0].counts, pattern_frame(salt=1))
    assert assembler.counters.duplicate_rows == 8


def test_sequence_wrap_keeps_frames_in_order() -> None:
    assembler = FrameAssembler()
    frames = push_all(assembler, blocks(65534) + blocks(65535) + blocks(0) + blocks(1))
    assert [f.seq for f in frames] == [65534, 65535, 0, 1]
    assert all(f.complete for f in frames)
    assert assembler.counters.duplicate_blocks + assembler.counters.late_blocks == 0


def test_restart_of_the_insole_sequence_is_accepted() -> None:
    assembler = FrameAssembler()
    push_all(assembler, blocks(5000) + blocks(5001)[:2])
    frames = push_all(assembler, blocks(0))
    assert [(f.seq, f.complete) for f in frames] == [(5001, False), (0, True)]
    assert assembler.counters.restarts == 1


def test_geometry_change_between_frames_and_mismatch_within_one() -> None:
    assembler = FrameAssembler()
    small = FrameRows(Foot.RIGHT, 1, 0, 16, 11, 10, 0, np.ones((16, 11), np.uint16))
    (frame,) = assembler.push(small)
    assert (frame.rows, frame.cols, frame.sample_bits) == (16, 11, 10)
    push_all(assembler, blocks(2, Foot.RIGHT)[:1])
    odd = FrameRows(Foot.RIGHT, 2, 0, 16, 22, 12, 8, np.ones((8, 22), np.uint16))
    assert assembler.push(odd) == []
    (frame,) = push_all(assembler, blocks(2, Foot.RIGHT)[1:])
    assert frame.complete
    assert frame.counts.shape == (32, 22)
    assert assembler.counters.geometry_mismatches == 1
    assert assembler.counters.geometry_changes == 1


def test_two_frames_in_progress_when_allowed() -> None:
    assembler = FrameAssembler(max_in_progress=2)
    a, b = blocks(7), blocks(8)
    frames = push_all(assembler, [a[0], b[0], a[1], b[1], b[2], b[3]])
    assert [(f.seq, f.complete) for f in frames] == [(7, False), (8, True)]
    assert assembler.in_progress == 0
    assert assembler.push(a[2]) == []  # frame 7 was emitted already
    assert assembler.counters.duplicate_blocks == 1


def test_bounded_in_progress_under_a_flood_of_new_seqs() -> None:
    assembler = FrameAssembler(max_in_progress=3)
    for seq in range(100):
        assembler.push(blocks(seq)[0])
        assert assembler.in_progress <= 3
    assert assembler.counters.frames_incomplete == 97


def test_refuses_zero_in_progress() -> None:
    with pytest.raises(ValueError, match="at least 1"):
        FrameAssembler(max_in_progress=0)
