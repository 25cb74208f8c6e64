"""Small synthetic session files for tests: known frames, both feet, row blocks.

``write_synthetic_session`` writes what a receiver board would have sent for
``frames`` foot-frame pairs at 16 Hz (each foot frame as row-block packets,
left then right) plus one label record per frame, and returns everything a
test needs to check what comes out the other end.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scotti.firmware_protocol.framing import encode_packet
from scotti.firmware_protocol.packets import Foot, FrameRows
from scotti.firmware_protocol.session import LabelRecord, SessionHeader, SessionWriter
from scotti.models.contract import (
    FRAME_COLS,
    FRAME_ROWS,
    MAX_COUNT,
    NUM_ACTIONS,
    SAMPLE_BITS,
    has_progress,
)
from scotti.models.insole import insole_mask

PERIOD_NS = 62_500_000  # 16 Hz
PERIOD_US = 62_500


# Random counts inside the insole outline, up to this: about 1 kN a foot, a plausible
# map for the model's input checks (models/input_checks.py), which call a map with
# load outside the outline or thousands of newtons "out_of_range". MAX_COUNT still
# crosses the wire: the last taxel of row 0 inside the outline is pinned to it.
SYNTHETIC_TOP = 1500
_OUTLINE = insole_mask()
_PINNED = (0, int(np.flatnonzero(_OUTLINE[0])[-1]))


def synthetic_counts(foot: int, seq: int) -> np.ndarray:
    """The (32, 22) uint16 frame a synthetic session carries for ``foot`` at ``seq``."""
    rng = np.random.default_rng(seq * 2 + int(foot))
    counts = rng.integers(0, SYNTHETIC_TOP + 1, size=(FRAME_ROWS, FRAME_COLS), dtype=np.uint16)
    counts[~_OUTLINE] = 0
    counts[_PINNED] = MAX_COUNT
    return counts


def frame_packets(
    foot: Foot, seq: int, clock_us: int, counts: np.ndarray, rows_per_packet: int = 8
) -> list[FrameRows]:
    """One foot frame cut into row blocks, as the radio sends it."""
    return [
        FrameRows(
            foot=foot,
            seq=seq,
            board_clock_us=clock_us,
            rows=FRAME_ROWS,
            cols=FRAME_COLS,
            sample_bits=SAMPLE_BITS,
            row_start=start,
            samples=counts[start : start + rows_per_packet],
        )
        for start in range(0, FRAME_ROWS, rows_per_packet)
    ]


@dataclass(frozen=True)
class SyntheticSession:
    path: Path
    frames: int  # foot-frame pairs written
    seqs: dict[Foot, list[int]]  # u16 seq of every frame written, per foot, in order
    records: list[tuple[int, bytes]]  # the packet records as written (t_ns, data)
    duration_ns: int  # t_ns of the last packet record minus the first

    @property
    def data(self) -> bytes:
        """Every byte of the packet records, in order."""
        return b"".join(data for _, data in self.records)

    def counts(self, foot: Foot, index: int) -> np.ndarray:
        return synthetic_counts(foot, self.seqs[foot][index])


def write_synthetic_session(
    path: Path,
    *,
    frames: int = 32,
    rows_per_packet: int = 8,
    seq_start: int = 0,
    right_seq_offset: int = 0,
    clock_start_us: int = 1_000_000,
    t0_ns: int = 1_000_000_000,
    feet: Sequence[Foot] = (Foot.LEFT, Foot.RIGHT),
    garbage_every: int = 0,
    labels: bool = True,
    counts_of: Callable[[Foot, int, int], np.ndarray] | None = None,
) -> SyntheticSession:
    """Write a session of ``frames`` frame pairs; see the module docstring.

    ``seq_start`` may sit near 65535 to exercise the wrap; ``right_seq_offset``
    makes the right board count from elsewhere. ``garbage_every=k`` adds a
    record of line noise after every k-th frame pair. ``counts_of(foot, seq, i)``
    replaces ``synthetic_counts`` (an empty insole, a stuck taxel, ...).
    """
    seqs: dict[Foot, list[int]] = {foot: [] for foot in feet}
    records: list[tuple[int, bytes]] = []
    header = SessionHeader(source="simulated", device="synthetic", scene={"name": "synthetic"})
    with SessionWriter(path, header) as writer:
        for i in range(frames):
            t_frame = t0_ns + i * PERIOD_NS
            t = t_frame
            for foot in feet:
                seq = (seq_start + i + (right_seq_offset if foot == Foot.RIGHT else 0)) % 65536
                clock = (clock_start_us + i * PERIOD_US + 7_000 * int(foot)) % (1 << 32)
                seqs[foot].append(seq)
                counts = (
                    synthetic_counts(foot, seq) if counts_of is None else counts_of(foot, seq, i)
                )
                for packet in frame_packets(foot, seq, clock, counts, rows_per_packet):
                    data = encode_packet(packet)
                    writer.write_packet(t, data)
                    records.append((t, data))
                    t += 1_000_000  # the radio spreads the blocks over a few ms
            if garbage_every and (i + 1) % garbage_every == 0:
                # Line noise that ends in a delimiter, so no real packet is lost to it.
                noise = bytes([0x55, 0x00, 0x13, 0x37, 0xFF, 0x00, 0x42, 0x00])
                writer.write_packet(t, noise)
                records.append((t, noise))
            if labels:
                writer.write_label(
                    LabelRecord(
                        seq=(seq_start + i) % 65536,
                        t_ns=t_frame,
                        keypoints=np.zeros((19, 3), dtype=np.float32),
                        action=i // 16 % NUM_ACTIONS,
                        progress=(i % 16) / 16 if has_progress(i // 16 % NUM_ACTIONS) else np.nan,
                        rep=0 if has_progress(i // 16 % NUM_ACTIONS) else -1,
                    )
                )
    return SyntheticSession(
        path=path,
        frames=frames,
        seqs=seqs,
        records=records,
        duration_ns=records[-1][0] - records[0][0],
    )
