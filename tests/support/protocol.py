"""Helpers for the firmware_protocol tests: deterministic frames and packets."""

from __future__ import annotations

import numpy as np
from scotti.firmware_protocol.packets import BoardStatus, Foot, FrameRows, InsoleStatus


def pattern_frame(rows: int = 32, cols: int = 22, salt: int = 0, bits: int = 12) -> np.ndarray:
    """A frame whose every sample is different and fits ``bits`` (zeros included)."""
    values = np.arange(rows * cols, dtype=np.int64).reshape(rows, cols) * 37 + salt * 101
    return (values % (1 << bits)).astype(np.uint16)


def whole_frame(foot: Foot = Foot.LEFT, seq: int = 1, clock: int = 1_000_000) -> FrameRows:
    return FrameRows(foot, seq, clock, 32, 22, 12, 0, pattern_frame(salt=seq))


def status() -> BoardStatus:
    return BoardStatus(
        uptime_s=3600,
        rx_packets=1000,
        radio_crc_errors=2,
        overflows=1,
        left=InsoleStatus(
            battery_mv=3700, battery_pct=64, rssi_dbm=-58, link_up=True, packets_lost=5
        ),
        right=InsoleStatus(),
    )
