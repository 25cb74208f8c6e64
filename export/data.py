"""Labelled session files -> training arrays, one slot per paired frame, and windows over them.

A session goes through the one frame path the daemon serves from
(``firmware_protocol.frame_path``: decode, assemble, pair, repair), so the
frames training reads are, byte for byte, the frames the daemon hands its
window on replay (tests/test_frame_path_parity.py). The repair rules are
the pairing's: missing rows come from that foot's previous frame, a foot
frame that never came is held (its previous frame repeated) for up to
``HOLD_FRAMES`` moments, then zero-filled; a short gap of both feet is
bridged, a longer one (``RESTART_GAP_FRAMES``) restarts the window, which
starts a new segment here; windows never cross segments. ``valid`` says which foot arrived
whole, ``repaired`` which was patched or held; ``WindowDataset`` drops, by
default, every window with an input frame that is neither (a zero-filled
foot: the daemon flags those moments as degraded, they are no training
material).

Each slot carries the pair's unwrapped sequence number (the left foot's,
the right's where the left was never heard) and the label of that number.

Decoded sessions are cached as ``.npz`` (keyed by path, size and mtime), so
repeated training runs do not decode again.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import tempfile
from collections import defaultdict, deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from scotti.export.errors import ExportError
from scotti.firmware_protocol.errors import SessionError
from scotti.firmware_protocol.frame_path import FramePath, PairSeq, stream_pairs
from scotti.firmware_protocol.packets import DEFAULT_COLS, DEFAULT_ROWS
from scotti.firmware_protocol.pairing import FILLED, HELD, PATCHED, WHOLE, PairedFrame
from scotti.firmware_protocol.session import LabelRecord, find_session_files, read_session
from scotti.firmware_protocol.wrap import seq_delta
from scotti.models import contract

log = logging.getLogger(__name__)

# Bump when the decoded arrays change meaning: old cache files are then ignored.
CACHE_VERSION = 4  # 4: one slot per paired frame, from the daemon's own frame path
SEQ_MODULUS = 1 << 16


class TrainingDataError(ExportError):
    """A session or a split that cannot be used for training (one-line message)."""


@dataclass(frozen=True)
class SessionArrays:
    """One session as the daemon pairs it: N slots, one per paired frame."""

    path: str
    subject: str
    frames: np.ndarray  # (N, H, 2W) uint16 counts, left foot columns 0..W-1, right W..2W-1
    valid: np.ndarray  # (N, 2) bool: that foot's frame arrived with all rows (left, right)
    repaired: np.ndarray  # (N, 2) bool: rows filled or frame held from the foot's previous
    seq: np.ndarray  # (N,) int64 unwrapped sequence number, +1 per slot but at a board restart
    segment: np.ndarray  # (N,) int32, increases where the daemon restarts its window
    has_label: np.ndarray  # (N,) bool
    keypoints: np.ndarray  # (N, 19, 3) float32 metres, NaN without a label
    action: np.ndarray  # (N,) int64 index into ACTIONS, NO_ACTION for a transition or no label
    progress: np.ndarray  # (N,) float32 in [0, 1], NaN where undefined (standing, transition)
    counters: dict[str, int] = field(default_factory=dict)  # what was bad, how often

    def __len__(self) -> int:
        return int(self.frames.shape[0])

    @property
    def frame_ok(self) -> np.ndarray:
        """(N,) bool: both feet arrived whole or were repaired (no zero-filled foot)."""
        return np.asarray((self.valid | self.repaired).all(axis=1))

    def slice(self, start: int, stop: int) -> SessionArrays:
        """Slots [start, stop) as a session of their own (a time split)."""
        s = np.s_[start:stop]
        return replace(
            self,
            frames=self.frames[s],
            valid=self.valid[s],
            repaired=self.repaired[s],
            seq=self.seq[s],
            segment=self.segment[s],
            has_label=self.has_label[s],
            keypoints=self.keypoints[s],
            action=self.action[s],
            progress=self.progress[s],
        )


def subject_of(subject: dict[str, Any] | None, path: Path) -> str:
    """The subject id: the header's ``subject`` dict ("id" or "name"), else the file stem."""
    if isinstance(subject, dict):
        for key in ("id", "name", "subject_id"):
            value = subject.get(key)
            if isinstance(value, str | int) and str(value):
                return str(value)
    return path.stem


def decode_session(path: Path) -> SessionArrays:
    """Decode one labelled session file into arrays (no cache)."""
    try:
        session = read_session(path)
    except SessionError as exc:  # names the file (and the place) already
        raise TrainingDataError(str(exc)) from None
    except OSError as exc:
        msg = f"{path}: {exc}"
        raise TrainingDataError(msg) from None
    geometry = (session.header.rows, session.header.cols)
    if geometry != (DEFAULT_ROWS, DEFAULT_COLS):
        msg = f"{path}: {geometry[0]} x {geometry[1]} frames; the model takes 32 x 22"
        raise TrainingDataError(msg)
    frame_path = FramePath()
    pairs = list(stream_pairs(((r.t_ns, r.data) for r in session.packets), frame_path))
    if not pairs:
        msg = f"{path}: no foot frames in the session"
        raise TrainingDataError(msg)
    made = frame_path.pairing.counters
    counters: dict[str, int] = {
        "bad_records": session.bad_records + session.unknown_records,
        "truncated": int(session.truncated),
        "decode_errors": frame_path.decoder.counters.errors,
        "wrong_geometry": made.bad_geometry,
        "duplicate_frames": made.duplicates + made.late,
        "incomplete_frames": made.rows_missing,
        "restarts": made.restarts,
        "resyncs": made.resyncs,
    }
    labels = sorted(session.labels, key=lambda lab: lab.t_ns)
    return _to_slots(
        path=path,
        subject=subject_of(session.header.subject, path),
        pairs=pairs,
        labels=labels,
        counters=counters,
    )


def _to_slots(
    *,
    path: Path,
    subject: str,
    pairs: Sequence[PairedFrame],
    labels: Sequence[LabelRecord],
    counters: dict[str, int],
) -> SessionArrays:
    n = len(pairs)
    frames = np.stack([p.counts for p in pairs])
    feet = np.array([p.feet for p in pairs])
    valid = feet == WHOLE
    repaired = (feet == PATCHED) | (feet == HELD)
    segment = np.cumsum([p.restart for p in pairs], dtype=np.int32)
    unwrap = PairSeq()
    seq = np.zeros(n, dtype=np.int64)
    for i, p in enumerate(pairs):
        ext = unwrap.of(p)
        seq[i] = ext if ext is not None else (seq[i - 1] + 1 if i else 0)
    counters["missing_left"] = int(np.isin(feet[:, 0], (HELD, FILLED)).sum())
    counters["missing_right"] = int(np.isin(feet[:, 1], (HELD, FILLED)).sum())
    counters["zero_filled"] = int((~(valid | repaired)).sum())

    has_label = np.zeros(n, dtype=bool)
    keypoints = np.full((n, contract.NUM_KEYPOINTS, 3), np.nan, dtype=np.float32)
    action = np.full(n, contract.NO_ACTION, dtype=np.int64)
    progress = np.full(n, np.nan, dtype=np.float32)
    bad_labels = 0
    for lab, slot in zip(labels, label_slots(seq, labels), strict=True):
        if slot is None:
            continue
        kp = np.asarray(_label_keypoints(lab), dtype=np.float32)
        act = int(lab.action)
        if kp.shape != (contract.NUM_KEYPOINTS, 3) or not -1 <= act < contract.NUM_ACTIONS:
            bad_labels += 1
            continue
        has_label[slot] = True
        keypoints[slot] = kp
        action[slot] = act
        # Progress only where the action has one: a label file's value for standing
        # or a transition is not trusted (an old writer may have put 0.5 there).
        progress[slot] = float(lab.progress) if contract.has_progress(act) else np.nan
    counters["bad_labels"] = bad_labels
    counters["unlabelled_slots"] = int(n - has_label.sum())
    return SessionArrays(
        path=str(path),
        subject=subject,
        frames=frames,
        valid=valid,
        repaired=repaired,
        seq=seq,
        segment=segment,
        has_label=has_label,
        keypoints=keypoints,
        action=action,
        progress=progress,
        counters=counters,
    )


def label_slots(seq: np.ndarray, labels: Sequence[LabelRecord]) -> list[int | None]:
    """The slot of each label (``None``: no pair at its time), labels in time order.

    Label seqs are unwrapped on the slots' axis; where a board restart makes a
    number come round again, the k-th label of a number goes to the k-th slot
    of it, so both pass in time order."""
    slots_of: dict[int, deque[int]] = defaultdict(deque)
    for slot, ext in enumerate(seq.tolist()):
        slots_of[ext].append(slot)
    ext = int(seq[0]) if len(seq) else 0
    prev = ext % SEQ_MODULUS
    out: list[int | None] = []
    for lab in labels:
        ext += seq_delta(lab.seq, prev)
        prev = lab.seq
        free = slots_of.get(ext)
        out.append(free.popleft() if free else None)
    return out


def _label_keypoints(label: Any) -> np.ndarray:
    kp = label.keypoints
    if isinstance(kp, bytes | bytearray | memoryview):
        return np.frombuffer(kp, dtype="<f4").reshape(-1, 3)
    return np.asarray(kp, dtype=np.float32).reshape(-1, 3)


# --- Cache -----------------------------------------------------------------

_ARRAYS = (
    "frames",
    "valid",
    "repaired",
    "seq",
    "segment",
    "has_label",
    "keypoints",
    "action",
    "progress",
)


def _cache_path(path: Path, cache_dir: Path) -> Path:
    st = path.stat()
    key = f"{CACHE_VERSION}|{path.resolve()}|{st.st_size}|{st.st_mtime_ns}"
    digest = hashlib.sha1(key.encode(), usedforsecurity=False).hexdigest()[:16]
    return cache_dir / f"{path.stem}.{digest}.npz"


def load_session(path: Path | str, cache_dir: Path | str | None = None) -> SessionArrays:
    """Decode a session, or read it from ``cache_dir`` when it was decoded before."""
    path = Path(path)
    if not path.is_file():
        msg = f"{path}: no such session file"
        raise TrainingDataError(msg)
    if cache_dir is None:
        return decode_session(path)
    cache_dir = Path(cache_dir)
    cached = _cache_path(path, cache_dir)
    if cached.is_file():
        try:
            with np.load(cached, allow_pickle=False) as z:
                meta = json.loads(str(z["meta"]))
                loaded = {name: z[name] for name in _ARRAYS}
            return SessionArrays(
                path=str(path), subject=meta["subject"], counters=meta["counters"], **loaded
            )
        except (OSError, ValueError, KeyError) as exc:
            log.warning("ignoring unreadable cache %s: %s", cached, exc)
    arrays = decode_session(path)
    _write_cache(arrays, cached)
    return arrays


def _write_cache(arrays: SessionArrays, cached: Path) -> None:
    cached.parent.mkdir(parents=True, exist_ok=True)
    meta = json.dumps({"subject": arrays.subject, "counters": arrays.counters})
    fd, tmp = tempfile.mkstemp(dir=cached.parent, suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez_compressed(f, meta=np.array(meta), **{n: getattr(arrays, n) for n in _ARRAYS})
        os.replace(tmp, cached)  # atomic: a killed run never leaves half a cache file
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def find_sessions(paths: Iterable[Path | str]) -> list[Path]:
    """Files given, plus every session file (by its magic) found under directories."""
    try:
        return find_session_files(paths)
    except SessionError as exc:
        raise TrainingDataError(str(exc)) from None
