"""The packet schedule of a whole session: which packet, when, with which clock.

One row per packet as the receiver forwards it: FRAME_ROWS blocks of each
foot frame, and a BOARD_STATUS once a second. Transport effects edit these
arrays (times, board clocks, masks) before a single byte is encoded; the
writer then encodes the kept packets in host-time order.

Nominal timing (no effects): frame ``k`` is sampled at host time
``t0 + k / rate``. Both insoles share one radio channel in time slots: the
frame period is cut into ``2 * blocks`` slots, left blocks first, then right,
each packet reaching the host ``RADIO_LATENCY_NS`` after its slot opens. The
status packet follows the last slot.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
from scotti.models.contract import FRAME_ROWS

STATUS: Final = -1  # ``foot`` of a BOARD_STATUS packet
RADIO_LATENCY_NS: Final = 2_000_000  # slot start to bytes at the host (radio + USB)
STATUS_EVERY_S: Final = 1.0
_STATUS_AFTER_SLOTS_NS: Final = 500_000  # status this long after the last slot's packet


@dataclass
class PacketSchedule:
    """Struct of arrays, one entry per packet, in nominal order."""

    t_ns: np.ndarray  # int64 host monotonic arrival time
    foot: np.ndarray  # int8: 0 left, 1 right, STATUS
    frame: np.ndarray  # int64 frame index (for status: the frame it follows)
    row_start: np.ndarray  # int16 first row of the block (0 for status)
    board_clock_us: np.ndarray  # int64 per packet, unwrapped (wrap at encoding)
    radio_lost: np.ndarray  # bool: the radio never delivered it (the receiver counts it)
    unplugged: np.ndarray  # bool: the receiver was off USB when it was due
    rows_per_block: int
    rate_hz: float
    t0_ns: int
    frames: int
    clock_start_us: tuple[int, int]

    @property
    def keep(self) -> np.ndarray:
        return np.asarray(~(self.radio_lost | self.unplugged))

    def frame_period_ns(self) -> int:
        return round(1e9 / self.rate_hz)


def build_schedule(
    frames: int,
    rate_hz: float,
    *,
    t0_ns: int,
    clock_start_us: tuple[int, int],
    rows_per_block: int = 8,
) -> PacketSchedule:
    """The clean schedule: every block of every frame of both feet, statuses once a second."""
    blocks = -(-FRAME_ROWS // rows_per_block)
    period_ns = round(1e9 / rate_hz)
    slot_ns = period_ns // (2 * blocks)
    frame_t = t0_ns + np.arange(frames, dtype=np.int64) * period_ns

    # Frame packets: (frame, foot, block) in slot order.
    k, foot, block = np.meshgrid(
        np.arange(frames, dtype=np.int64), np.arange(2), np.arange(blocks), indexing="ij"
    )
    slot = foot * blocks + block
    t_frame = frame_t[k] + RADIO_LATENCY_NS + slot * slot_ns
    period_us = 1e6 / rate_hz
    clock = np.asarray(clock_start_us, dtype=np.int64)[foot] + np.rint(k * period_us).astype(
        np.int64
    )

    # Status packets: after the last slot of every STATUS_EVERY_S-th frame.
    every = max(1, round(STATUS_EVERY_S * rate_hz))
    sk = np.arange(every - 1, frames, every, dtype=np.int64)
    t_status = frame_t[sk] + RADIO_LATENCY_NS + (2 * blocks - 1) * slot_ns
    t_status += _STATUS_AFTER_SLOTS_NS

    # Merge: statuses follow their frame's packets.
    n_frame = k.size
    t = np.concatenate([t_frame.ravel(), t_status])
    order = np.argsort(t, kind="stable")
    sched_foot = np.concatenate([foot.ravel(), np.full(len(sk), STATUS)]).astype(np.int8)
    sched_frame = np.concatenate([k.ravel(), sk])
    row_start = np.concatenate([(block * rows_per_block).ravel(), np.zeros(len(sk))])
    clocks = np.concatenate([clock.ravel(), np.zeros(len(sk), dtype=np.int64)])
    total = n_frame + len(sk)
    return PacketSchedule(
        t_ns=t[order],
        foot=sched_foot[order],
        frame=sched_frame[order],
        row_start=row_start[order].astype(np.int16),
        board_clock_us=clocks[order],
        radio_lost=np.zeros(total, dtype=bool),
        unplugged=np.zeros(total, dtype=bool),
        rows_per_block=rows_per_block,
        rate_hz=rate_hz,
        t0_ns=t0_ns,
        frames=frames,
        clock_start_us=clock_start_us,
    )


def frame_times_ns(schedule: PacketSchedule) -> np.ndarray:
    """Nominal host time of every frame's sampling instant (label times)."""
    period_ns = schedule.frame_period_ns()
    return schedule.t0_ns + np.arange(schedule.frames, dtype=np.int64) * period_ns
