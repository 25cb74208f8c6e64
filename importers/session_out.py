"""Imported frames and labels into a session file, as a board and the simulator write them.

Each frame of each foot goes in as one FRAME_ROWS packet carrying all 32
rows (PROTOCOL.md allows a whole frame per packet), COBS-framed as on the
wire (``encode_whole_frames``: many packets at once, byte for byte what
``encode_packet(FrameRows(...))`` gives); both feet of a frame share one
packet record, stamped with the frame's time on the source's clock. The insole clock is that time in
microseconds (wrapping as the protocol says). Label records follow the
same sequence numbers; source frames (thinned) let pictures show the grid
the recording came on.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Final

import numpy as np
from scotti.firmware_protocol.framing import encode_whole_frames
from scotti.firmware_protocol.packets import CLOCK_MODULUS, SEQ_MODULUS, Foot
from scotti.firmware_protocol.session import (
    LabelRecord,
    PacketRecord,
    SessionHeader,
    SessionWriter,
    SourceFrameRecord,
)
from scotti.models.contract import (
    FRAME_COLS,
    FRAME_RATE_HZ,
    FRAME_ROWS,
    NO_ACTION,
    NUM_KEYPOINTS,
    SAMPLE_BITS,
)

_BATCH: Final = 256  # frames encoded at once (their bytes stay in cache)
_GEOMETRY: Final = (FRAME_ROWS, FRAME_COLS, SAMPLE_BITS)


@dataclass(frozen=True)
class ImportedFrames:
    """Everything that goes into the file, on the 16 Hz timeline."""

    times: np.ndarray  # (M,) float64 seconds, the source's clock
    seq: np.ndarray  # (M,) int64 unwrapped
    counts: np.ndarray  # (M, 2, 32, 22) uint16
    keypoints: np.ndarray | None  # (M, 19, 3) float32 pose frame, NaN where masked
    action: np.ndarray | None  # (M,) int64, NO_ACTION where none
    progress: np.ndarray | None  # (M,) float32, NaN where missing
    repetition: np.ndarray | None  # (M,) int32, -1 where none


def write_imported(
    path: str | os.PathLike[str],
    frames: ImportedFrames,
    *,
    device: str,
    created_unix: float,
    subject: dict[str, Any] | None,
    provenance: dict[str, Any],
    source_frames: Sequence[SourceFrameRecord] = (),
    feet: Sequence[str] = ("left", "right"),
    overwrite: bool = False,
) -> int:
    """Write the session; returns the number of label records written.

    Packets go out for the ``feet`` named only: a foot the recording does
    not hold sends nothing, as an insole that is off sends nothing to its
    receiver (the daemon then reports it silent).
    """
    header = SessionHeader(
        source="imported",
        device=device,
        rows=FRAME_ROWS,
        cols=FRAME_COLS,
        sample_bits=SAMPLE_BITS,
        rate_hz=FRAME_RATE_HZ,
        created_unix=created_unix,
        subject=subject,
        imported=provenance,
    )
    t_ns: list[int] = np.rint(frames.times * 1e9).astype(np.int64).tolist()
    seq = frames.seq % SEQ_MODULUS
    clock = np.rint(frames.times * 1e6).astype(np.int64) % CLOCK_MODULUS
    seq_list: list[int] = seq.tolist()
    labelled: list[bool] = _labelled(frames).tolist()
    label_of = _Labels(frames)
    pending_sources = sorted(source_frames, key=lambda r: r.t_ns)
    next_source = 0
    labels = 0
    held = [k for k, name in enumerate(("left", "right")) if name in feet]
    codes = [(int(Foot.LEFT), int(Foot.RIGHT))[k] for k in held]
    per = len(held)  # packets per frame
    with SessionWriter(path, header, flush_each=False, overwrite=overwrite) as writer:
        for start in range(0, len(t_ns), _BATCH):
            stop = min(start + _BATCH, len(t_ns))
            encoded = encode_whole_frames(
                np.tile(codes, stop - start),
                np.repeat(seq[start:stop], per),
                np.repeat(clock[start:stop], per),
                _held(frames.counts[start:stop], held).reshape(-1, FRAME_ROWS, FRAME_COLS),
                SAMPLE_BITS,
            )
            batch: list[PacketRecord | LabelRecord | SourceFrameRecord] = []
            for k in range(start, stop):
                while next_source < len(pending_sources) and (
                    pending_sources[next_source].t_ns <= t_ns[k]
                ):
                    batch.append(pending_sources[next_source])
                    next_source += 1
                if labelled[k]:
                    batch.append(label_of(k, seq_list[k], t_ns[k]))
                    labels += 1
                i = per * (k - start)
                batch.append(PacketRecord(t_ns[k], b"".join(encoded[i : i + per])))
            writer.write_many(batch)
        writer.write_many(pending_sources[next_source:])
    return labels


def _held(counts: np.ndarray, held: list[int]) -> np.ndarray:
    """(n, len(held), 32, 22): both feet as they are (a view), or the one held."""
    return counts if len(held) == counts.shape[1] else counts[:, held]


def _labelled(frames: ImportedFrames) -> np.ndarray:
    """Frames with anything to learn from: a keypoint or an action."""
    n = frames.times.size
    has = np.zeros(n, dtype=bool)
    if frames.keypoints is not None:
        has |= np.isfinite(frames.keypoints).all(axis=2).any(axis=1)
    if frames.action is not None:
        has |= frames.action >= 0
    return has


class _Labels:
    """Each frame's label record; the columns taken out of numpy once, not per frame."""

    def __init__(self, frames: ImportedFrames) -> None:
        n = frames.times.size
        none = np.full((NUM_KEYPOINTS, 3), np.nan, dtype=np.float32)
        self.keypoints = [none] * n if frames.keypoints is None else list(frames.keypoints)
        self.action = [NO_ACTION] * n if frames.action is None else frames.action.tolist()
        nan = float("nan")
        self.progress = [nan] * n if frames.progress is None else frames.progress.tolist()
        self.rep = [-1] * n if frames.repetition is None else frames.repetition.tolist()

    def __call__(self, k: int, seq: int, t_ns: int) -> LabelRecord:
        return LabelRecord(
            seq=seq,
            t_ns=t_ns,
            keypoints=self.keypoints[k],
            action=self.action[k],
            progress=self.progress[k],
            rep=self.rep[k],
        )
