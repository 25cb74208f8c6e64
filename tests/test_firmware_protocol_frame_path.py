"""The frame path's shortcut for blocks as they come off the wire (``push_raw``: bytes kept,
joined once) gives exactly what the general way (a ``FrameRows`` per block, ``push``) gives:
the same foot frames, pairs and counters, on streams that lose, repeat, reorder and mangle
blocks, restart boards, change geometry, and cut packets across reads at random."""

from __future__ import annotations

import numpy as np
import pytest
from scotti.firmware_protocol.assembly import FootFrame
from scotti.firmware_protocol.frame_path import FramePath, FrameWatch
from scotti.firmware_protocol.framing import encode_packet
from scotti.firmware_protocol.packets import Foot, FrameRows
from scotti.firmware_protocol.pairing import PairedFrame

from tests.support.protocol import status

PERIOD_US = 62_500


class Frames(FrameWatch):
    """Sees foot frames only: blocks take the shortcut."""

    def __init__(self) -> None:
        self.frames: list[FootFrame] = []

    def frame(self, frame: FootFrame) -> None:
        self.frames.append(frame)


class BlocksAndFrames(Frames):
    """Sees every block too: each becomes a FrameRows and goes the general way."""

    def __init__(self) -> None:
        super().__init__()
        self.blocks = 0

    def block(self, block: FrameRows) -> None:
        self.blocks += 1


def messy_stream(seed: int, frames: int = 120) -> bytes:
    """Both feet's frames as row blocks, with what radios and boards do wrong."""
    rng = np.random.default_rng(seed)
    out: list[bytes] = []
    seqs = [int(rng.integers(0, 65536)), int(rng.integers(0, 65536))]
    previous: list[list[bytes]] = [[], []]  # each foot's last frame's blocks
    for i in range(frames):
        for foot in (Foot.LEFT, Foot.RIGHT):
            seqs[foot] = (seqs[foot] + 1 + int(rng.random() < 0.05)) % 65536  # frames lost
            if rng.random() < 0.01:
                seqs[foot] = int(rng.integers(0, 65536))  # the board restarted
            cols = 22 if rng.random() > 0.03 else 20  # a frame of another geometry
            bits = 12 if rng.random() > 0.05 else 6  # samples too narrow for the shortcut
            counts = rng.integers(0, 1 << bits, (32, cols), dtype=np.uint16)
            counts[rng.random((32, cols)) < 0.8] = 0
            per_block = 8 if rng.random() > 0.1 else 5
            blocks = [
                encode_packet(
                    FrameRows(foot, seqs[foot], (i * PERIOD_US) % (1 << 32), 32, cols, bits,
                              start, counts[start : start + per_block])
                )
                for start in range(0, 32, per_block)
            ]  # fmt: skip
            if rng.random() < 0.08:
                del blocks[int(rng.integers(len(blocks)))]  # a block lost
            if rng.random() < 0.05:
                blocks.insert(int(rng.integers(len(blocks))), blocks[0])  # a block repeated
            if rng.random() < 0.08 and len(blocks) > 1:
                j = int(rng.integers(len(blocks) - 1))
                blocks[j], blocks[j + 1] = blocks[j + 1], blocks[j]  # two swapped
            if rng.random() < 0.05 and previous[foot]:
                blocks.insert(1, previous[foot][-1])  # a block of the frame before, late
            if rng.random() < 0.03:
                odd = FrameRows(foot, seqs[foot], 0, 32, 20, 12, 8, counts[8:16, :20])
                blocks.insert(1, encode_packet(odd))  # a block of another geometry
            previous[foot] = blocks
            if rng.random() < 0.03:
                j = int(rng.integers(len(blocks)))
                bad = bytearray(blocks[j])
                bad[int(rng.integers(len(bad) - 1))] ^= 0x5A  # line noise
                blocks[j] = bytes(bad)
            out += blocks
        if rng.random() < 0.05:
            out.append(encode_packet(status()))
        if rng.random() < 0.02:
            out.append(rng.integers(1, 256, int(rng.integers(1, 40)), dtype=np.uint8).tobytes())
    return b"".join(out)


def run(stream: bytes, cuts: list[int], watch: Frames) -> tuple[list[PairedFrame], FramePath]:
    path = FramePath(watch=watch)
    pairs: list[PairedFrame] = []
    for n, (start, end) in enumerate(zip([0, *cuts], [*cuts, len(stream)], strict=True)):
        pairs += path.feed(stream[start:end], 1_000 * n)
    pairs += path.end()
    return pairs, path


def pair_key(pair: PairedFrame) -> tuple[object, ...]:
    return (
        pair.counts.tobytes(),
        pair.counts.shape,
        pair.seqs,
        pair.clocks,
        pair.last_byte_mono_ns,
        pair.flags,
        pair.restart,
        pair.feet,
    )


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize("reads", ["whole packets", "random cuts"])
def test_the_shortcut_gives_what_the_general_way_gives(seed: int, reads: str) -> None:
    stream = messy_stream(seed)
    if reads == "whole packets":
        cuts = [i + 1 for i in range(len(stream) - 1) if stream[i] == 0]
    else:
        rng = np.random.default_rng(seed + 100)
        cuts = sorted(set(rng.integers(1, len(stream), len(stream) // 300).tolist()))
    fast_watch, slow_watch = Frames(), BlocksAndFrames()
    fast, fast_path = run(stream, cuts, fast_watch)
    slow, slow_path = run(stream, cuts, slow_watch)
    assert slow_watch.blocks > 0
    assert fast_path.assembler.counters.blocks == slow_watch.blocks
    assert len(fast) > 50
    assert fast_watch.frames == slow_watch.frames
    assert [pair_key(p) for p in fast] == [pair_key(p) for p in slow]
    assert fast_path.decoder.counters == slow_path.decoder.counters
    assert fast_path.assembler.counters == slow_path.assembler.counters
    assert fast_path.pairing.counters == slow_path.pairing.counters
    assert fast_path.board_status == slow_path.board_status
    # The stream is as messy as meant: every kind of repair happened somewhere.
    counted = fast_path.assembler.counters
    assert counted.frames_incomplete
    assert counted.geometry_changes
    assert counted.geometry_mismatches
    assert counted.duplicate_blocks + counted.late_blocks
    assert fast_path.decoder.counters.errors


def test_a_whole_frame_off_the_wire_is_read_only_and_marks_no_row_missing() -> None:
    counts = np.arange(32 * 22, dtype=np.uint16).reshape(32, 22)
    data = b"".join(
        encode_packet(FrameRows(Foot.LEFT, 7, 1_000, 32, 22, 12, start, counts[start : start + 8]))
        for start in range(0, 32, 8)
    )
    watch = Frames()
    FramePath(watch=watch).feed(data, 5)
    (frame,) = watch.frames
    assert frame.complete
    assert np.array_equal(frame.counts, counts)
    assert not frame.counts.flags.writeable
    assert not frame.rows_missing.any()
    assert not frame.rows_missing.flags.writeable
    assert (frame.seq, frame.board_clock_us, frame.last_byte_ns) == (7, 1_000, 5)
