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


def write_demo_session(
    path: object,
    frames: int = 20,
    skip_seqs: tuple[int, ...] = (),
    drop_block: tuple[int, int] | None = None,
    start_seq: int = 0,
) -> None:
    """A small simulated session: both feet, 4 blocks of 8 rows per frame, labels, status.

    ``skip_seqs``: frames never sent; ``drop_block``: (seq, block index) lost on the left.
    Garbage is put in front of the stream, as when a port opens mid-packet.
    """
    from pathlib import Path

    from scotti.firmware_protocol.framing import encode_packet
    from scotti.firmware_protocol.packets import frame_blocks
    from scotti.firmware_protocol.session import LabelRecord, SessionHeader, SessionWriter

    header = SessionHeader(
        source="simulated", device="demo", created_unix=1.7e9, scene={"name": "demo", "seed": 1}
    )
    t_ns = 10**9
    with SessionWriter(Path(str(path)), header) as writer:
        writer.write_packet(t_ns, b"\x13\x37\xbe\xef\x00")
        for i in range(frames):
            seq = (start_seq + i) % 65536
            t_ns += 62_500_000
            if seq in skip_seqs:
                continue
            chunk = b""
            for foot in (Foot.LEFT, Foot.RIGHT):
                for k, block in enumerate(
                    frame_blocks(foot, seq, (seq * 62_500) % 2**32, pattern_frame(salt=seq))
                ):
                    if foot == Foot.LEFT and drop_block == (seq, k):
                        continue
                    chunk += encode_packet(block)
            if i % 16 == 0:
                chunk += encode_packet(status())
            writer.write_packet(t_ns, chunk)
            keypoints = np.zeros((19, 3), np.float32)
            writer.write_label(LabelRecord(seq, t_ns, keypoints, i % 2 - 1, 0.5, 0))
