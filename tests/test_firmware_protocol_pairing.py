"""Pairing left/right foot frames: offsets, wraps, duplicates, reordering, silence, gaps."""

from __future__ import annotations

import numpy as np
from scotti.firmware_protocol import pairing as rules
from scotti.firmware_protocol.assembly import FootFrame
from scotti.firmware_protocol.packets import Foot
from scotti.firmware_protocol.pairing import (
    FILLED,
    HELD,
    PARTIAL,
    PATCHED,
    WHOLE,
    PairedFrame,
    Pairing,
)
from scotti.models import contract
from scotti.models.contract import FRAME_COLS, FRAME_ROWS

L, R = Foot.LEFT, Foot.RIGHT
PERIOD_US = 62_500
PERIOD_NS = 62_500_000


def counts_for(foot: Foot, i: int) -> np.ndarray:
    """A frame whose every taxel says which foot and which moment it is."""
    return np.full((FRAME_ROWS, FRAME_COLS), 100 * int(foot) + i % 100 + 1, dtype=np.uint16)


def frame(
    foot: Foot,
    i: int,
    *,
    seq0: int = 0,
    clock0: int = 5_000_000,
    missing: tuple[int, ...] = (),
    counts: np.ndarray | None = None,
) -> FootFrame:
    """The frame of moment ``i`` from a board whose counters started at seq0/clock0."""
    c = counts_for(foot, i) if counts is None else counts
    rows_missing = np.zeros(FRAME_ROWS, dtype=bool)
    rows_missing[list(missing)] = True
    c = c.copy()
    c[rows_missing] = 0  # as the assembler leaves them
    return FootFrame(
        foot=foot,
        seq=(seq0 + i) % 65536,
        board_clock_us=(clock0 + i * PERIOD_US) % (1 << 32),
        counts=c,
        rows_missing=rows_missing,
        complete=not missing,
        last_byte_ns=1_000_000_000 + i * PERIOD_NS + int(foot) * 1_000_000,
    )


def feed(pairing: Pairing, frames: list[FootFrame]) -> list[PairedFrame]:
    out: list[PairedFrame] = []
    for f in frames:
        out += pairing.push(f)
    return out


def moments(pairs: list[PairedFrame]) -> list[tuple[int, int]]:
    """(left moment, right moment) each pair carries, read back from the counts."""
    return [(int(p.counts[0, 0]) - 1, int(p.counts[0, FRAME_COLS]) - 101) for p in pairs]


def both(n: int, start: int = 0, seq0: int = 0) -> list[FootFrame]:
    return [
        f for i in range(start, start + n) for f in (frame(L, i, seq0=seq0), frame(R, i, seq0=seq0))
    ]


def test_pairs_in_order_with_no_latency_when_both_feet_arrive() -> None:
    pairing = Pairing()
    out: list[PairedFrame] = []
    for i in range(10):
        assert pairing.push(frame(L, i)) == []  # waits for the right foot
        got = pairing.push(frame(R, i))
        assert len(got) == 1
        out += got
    assert moments(out) == [(i, i) for i in range(10)]
    assert all(p.flags == () and not p.restart for p in out)
    assert out[3].seqs == (3, 3)
    assert out[3].clocks == (5_000_000 + 3 * PERIOD_US,) * 2
    assert out[3].counts.shape == (FRAME_ROWS, 2 * FRAME_COLS)
    assert out[3].last_byte_mono_ns == frame(R, 3).last_byte_ns


def test_offset_seqs_and_clocks_of_the_two_boards_are_learned() -> None:
    pairing = Pairing()
    frames = [
        f
        for i in range(12)
        for f in (frame(L, i, seq0=65530), frame(R, i, seq0=1234, clock0=4_000_000_000))
    ]
    out = feed(pairing, frames)
    assert moments(out) == [(i, i) for i in range(12)]  # the left seq wrapped at 65536
    assert out[8].seqs == ((65530 + 8) % 65536, 1242)
    assert pairing.counters.resyncs == 0


def test_duplicates_are_dropped_and_reordering_is_tolerated() -> None:
    pairing = Pairing()
    frames = [
        *both(2),
        frame(L, 3),  # L2 and L3 swapped
        frame(L, 2),
        frame(R, 2),
        frame(R, 2),  # duplicate
        frame(R, 3),
        frame(L, 3),  # duplicate after its moment went out
        *both(2, start=4),
    ]
    out = feed(pairing, frames)
    assert moments(out) == [(i, i) for i in range(6)]
    assert pairing.counters.duplicates == 2
    assert all(p.flags == () for p in out)


def test_a_frame_later_than_its_moment_is_dropped_as_late() -> None:
    pairing = Pairing()
    frames = [*both(2), frame(R, 2), *both(3, start=3), frame(L, 2)]
    out = feed(pairing, frames)
    assert moments(out)[2] == (1, 2)  # the left was held while it was missing
    assert "left_held" in out[2].flags
    assert pairing.counters.late == 1
    assert len(out) == 6


def test_a_silent_foot_is_held_then_filled_and_reported_silent() -> None:
    pairing = Pairing()
    out = feed(pairing, both(4))
    assert pairing.foot_states() == {"left": "ok", "right": "ok"}
    assert feed(pairing, [frame(L, 4), frame(L, 5)]) == []  # waits reorder_frames (2)
    lefts = [frame(L, i) for i in range(6, 30)]
    out += feed(pairing, lefts)
    silent = out[4:]
    assert len(silent) == 2 + len(lefts)  # then at the left's pace
    hold = pairing.config.hold_frames  # 8 = 0.5 s
    assert all(p.flags == ("right_held",) for p in silent[:hold])
    assert all(p.feet == (WHOLE, HELD) for p in silent[:hold])
    assert all(int(p.counts[0, FRAME_COLS]) == 101 + 3 for p in silent[:hold])  # R3 repeated
    assert silent[0].seqs == (4, 4)  # the seq the right board would have sent
    assert silent[0].clocks[1] == 5_000_000 + 4 * PERIOD_US
    assert all(p.flags == ("right_filled",) for p in silent[hold:])
    assert all(p.feet == (WHOLE, FILLED) for p in silent[hold:])
    assert not silent[hold].counts[:, FRAME_COLS:].any()
    assert pairing.foot_states() == {"left": "ok", "right": "silent"}
    assert pairing.counters.held == [0, hold]
    # The right foot comes back and pairs again at once.
    back = feed(pairing, both(3, start=30))
    assert pairing.foot_states() == {"left": "ok", "right": "ok"}
    assert moments(back)[-2:] == [(31, 31), (32, 32)]
    assert back[-1].flags == ()


def test_a_foot_that_never_speaks_is_filled_from_the_start() -> None:
    pairing = Pairing()
    assert feed(pairing, [frame(R, 0), frame(R, 1)]) == []
    out = feed(pairing, [frame(R, i) for i in range(2, 12)])
    assert len(out) == 12
    assert all(p.flags == ("left_filled",) for p in out)
    assert all(p.seqs[0] == -1 for p in out)
    assert pairing.counters.filled == [12, 0]


def test_missing_rows_are_taken_from_the_previous_frame_of_that_foot() -> None:
    pairing = Pairing()
    out = feed(pairing, [*both(1), frame(L, 1, missing=(0, 5, 31)), frame(R, 1)])
    assert out[1].flags == ("rows_missing",)
    assert out[1].feet == (PATCHED, WHOLE)
    left = out[1].counts[:, :FRAME_COLS]
    assert (left[0, 0], left[5, 3], left[31, 21]) == (1, 1, 1)  # from moment 0
    assert left[1, 0] == 2  # its own rows kept
    assert pairing.counters.rows_missing == 1


def test_missing_rows_of_a_foot_s_first_frame_stay_zero_and_say_so() -> None:
    pairing = Pairing()
    out = feed(pairing, [frame(L, 0), frame(R, 0, missing=(2, 3)), *both(2, start=1)])
    assert out[0].feet == (WHOLE, PARTIAL)
    assert out[0].flags == ("rows_missing",)
    assert not out[0].counts[2:4, FRAME_COLS:].any()
    assert [p.feet for p in out[1:]] == [(WHOLE, WHOLE)] * 2


def test_the_repair_rules_are_the_model_contract_s() -> None:
    assert rules.FRAME_RATE_HZ == contract.FRAME_RATE_HZ
    assert rules.HOLD_FRAMES == contract.SILENT_FOOT_HOLD_FRAMES
    assert rules.RESTART_GAP_FRAMES == contract.WINDOW_RESTART_GAP_FRAMES


def test_a_short_gap_of_both_feet_is_bridged_a_long_one_restarts() -> None:
    pairing = Pairing()
    out = feed(pairing, both(5))
    out += feed(pairing, both(3, start=10))  # 5 moments lost (0.31 s)
    assert moments(out)[5:10] == [(4, 4)] * 5
    assert all(p.flags == ("left_held", "right_held") for p in out[5:10])
    assert moments(out)[10:] == [(10, 10), (11, 11), (12, 12)]
    assert out[10].flags == ()
    assert pairing.counters.gaps == 5
    assert not any(p.restart for p in out)
    # 2 s of silence: no frames are invented; the window starts over.
    after = feed(pairing, both(3, start=45))
    assert moments(after) == [(45, 45), (46, 46), (47, 47)]
    assert [p.restart for p in after] == [True, False, False]
    assert pairing.counters.restarts == 1


def test_a_board_that_restarts_its_counters_is_followed() -> None:
    pairing = Pairing()
    out = feed(pairing, both(20))
    # Both boards start over (a loop of a replay, or a reset) but keep sending.
    frames = [
        f for i in range(20, 26) for f in (frame(L, i, seq0=-20), frame(R, i, seq0=-20, clock0=1))
    ]
    out += feed(pairing, frames)
    assert moments(out) == [(i, i) for i in range(26)]
    assert pairing.counters.resyncs == 2
    assert pairing.counters.restarts == 0


def test_reset_learns_again_and_flags_the_restart() -> None:
    pairing = Pairing()
    feed(pairing, both(5))
    pairing.reset()
    out = feed(pairing, both(3, seq0=900))
    assert moments(out) == [(0, 0), (1, 1), (2, 2)]
    assert out[0].restart
    assert out[0].seqs == (900, 900)


def test_flush_sends_what_waits_holding_the_missing_foot() -> None:
    pairing = Pairing()
    out = feed(pairing, [*both(2), frame(L, 2)])
    assert len(out) == 2
    tail = pairing.flush()
    assert len(tail) == 1
    assert tail[0].flags == ("right_held",)


def test_a_frame_of_the_wrong_geometry_is_counted_not_paired() -> None:
    pairing = Pairing()
    odd = FootFrame(
        foot=L,
        seq=0,
        board_clock_us=0,
        counts=np.zeros((16, 22), dtype=np.uint16),
        rows_missing=np.zeros(16, dtype=bool),
    )
    assert pairing.push(odd) == []
    assert pairing.counters.bad_geometry == 1
