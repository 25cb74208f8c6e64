"""Small labelled session files for the training tests, written with the real writer.

Frame k of a synthetic stream has sequence number (first_seq + k) mod 2**16,
so a ``first_seq`` near 65535 makes the stream wrap. Its pressure encodes k:
taxel (0, 0) of both feet reads k + 1 and a blob moves with k, so a window's
content tells which frame it ends at. Labels are functions of k too.
"""

from __future__ import annotations

from collections.abc import Collection
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from scotti.firmware_protocol import (
    Foot,
    FrameRows,
    LabelRecord,
    SessionHeader,
    SessionWriter,
    encode_packet,
)
from scotti.models import contract

if TYPE_CHECKING:
    from scotti.export.model import Scotti

ROWS, COLS = contract.FRAME_ROWS, contract.FRAME_COLS
ROW_BLOCK = 8  # rows per packet, as the simulator sends them (4 packets per foot frame)
PERIOD = 24  # frames per synthetic repetition
# The model the training tests train: big enough to learn the synthetic stream, small
# enough that a CPU trains it in seconds. Tests that need dropout copy it with their own.
TINY_MODEL: dict[str, Any] = {
    "window": 8,
    "embed_dim": 16,
    "layers": 1,
    "heads": 2,
    "head_hidden": 16,
    "conv_channels": [4, 4],
    "dropout": 0.0,
}


def tiny_model(seed: int, dropout: float = 0.0) -> Scotti:
    """A ``Scotti`` of ``TINY_MODEL``'s size with seeded weights (needs torch)."""
    import torch
    from scotti.export.model import Scotti, ScottiConfig

    torch.manual_seed(seed)
    return Scotti(ScottiConfig.from_dict({**TINY_MODEL, "dropout": dropout}))


def foot_counts(k: int, foot: int) -> np.ndarray:
    """(ROWS, COLS) uint16 of frame k: k + 1 at (0, 0) and a blob that walks with k."""
    counts = np.zeros((ROWS, COLS), dtype=np.uint16)
    phase = (k % PERIOD) / PERIOD
    r = int(4 + phase * (ROWS - 8))
    c = 2 + 9 * foot + (k // PERIOD) % contract.NUM_ACTIONS  # the blob column tells the action
    counts[r - 2 : r + 3, c - 2 : c + 3] = 1500 + 400 * foot
    counts[0, 0] = k + 1
    return counts


def label_for(k: int) -> tuple[np.ndarray, int, float]:
    """Keypoints (19, 3), action and progress of frame k."""
    phase = (k % PERIOD) / PERIOD
    action = (k // PERIOD) % contract.NUM_ACTIONS
    if (k // PERIOD) % 5 == 4:
        action = contract.NO_ACTION  # a stand now and then
    kp = np.zeros((contract.NUM_KEYPOINTS, 3), dtype=np.float32)
    kp[:, 2] = np.linspace(0.0, 1.7, contract.NUM_KEYPOINTS, dtype=np.float32)
    kp[:, 0] = 0.2 * np.sin(2 * np.pi * phase) + 0.01 * np.arange(contract.NUM_KEYPOINTS)
    kp[:, 1] = 0.05 * action
    progress = phase if contract.has_progress(action) else float("nan")  # standing: none
    return kp, action, progress


def write_session(
    path: Path,
    frames: int,
    *,
    first_seq: int = 0,
    subject: str | None = "s1",
    drop_foot: Collection[tuple[int, int]] = (),
    drop_rows: Collection[tuple[int, int, int]] = (),
    garbage_every: int = 0,
    seq_jump: tuple[int, int] = (0, 0),
    restart: tuple[int, int] | None = None,
) -> Path:
    """Write ``frames`` frames (both feet, 4 row packets each) and a label per frame.

    ``drop_foot``: (k, foot) pairs whose whole frame is never sent.
    ``drop_rows``: (k, foot, block) triples whose row block is never sent.
    ``garbage_every``: put junk bytes on the line before every n-th frame.
    ``seq_jump``: (k, n): from frame k on, sequence numbers, board clock and host time are
    n frames further on (an outage: nothing was sent for n frames).
    ``restart``: (k, seq): from frame k on, the boards count again from ``seq``, their
    clocks from 0 (both insoles restarted; the host's time goes on).
    """
    header = SessionHeader(source="simulated", subject={"id": subject} if subject else None)
    t0 = 1_000_000_000
    with SessionWriter(path, header, overwrite=True) as w:  # tests rewrite a file in place
        for k in range(frames):
            step = k + (seq_jump[1] if k >= seq_jump[0] > 0 else 0)
            seq, clock = (first_seq + step) % (1 << 16), step * 62_500
            if restart is not None and k >= restart[0]:
                seq, clock = (restart[1] + k - restart[0]) % (1 << 16), (k - restart[0]) * 62_500
            t_ns = t0 + step * 62_500_000
            if garbage_every and k % garbage_every == 0:
                w.write_packet(t_ns, b"\x13\x37garbage\x00")
            for foot in (Foot.LEFT, Foot.RIGHT):
                if (k, int(foot)) in drop_foot:
                    continue
                counts = foot_counts(k, int(foot))
                for block in range(ROWS // ROW_BLOCK):
                    if (k, int(foot), block) in drop_rows:
                        continue
                    rows = FrameRows(
                        foot=foot,
                        seq=seq,
                        board_clock_us=clock % (1 << 32),
                        rows=ROWS,
                        cols=COLS,
                        sample_bits=contract.SAMPLE_BITS,
                        row_start=block * ROW_BLOCK,
                        samples=counts[block * ROW_BLOCK : (block + 1) * ROW_BLOCK],
                    )
                    w.write_packet(t_ns, encode_packet(rows))
            kp, action, progress = label_for(k)
            w.write_label(LabelRecord(seq, t_ns, kp, action, progress, k // PERIOD))
    return path
