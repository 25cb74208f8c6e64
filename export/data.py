"""Labelled session files -> training arrays on a sequence grid, and windows over them.

A session is decoded exactly as the daemon decodes it (StreamDecoder, then
FrameAssembler), left and right foot frames are joined by their shared
sequence number, and labels are attached per sequence number. Sequence
numbers wrap at 2**16; they are unwrapped into one int64 timeline.

Missing data is repaired as the daemon repairs it live (daemon/frames/pairing.py),
so the model trains on what it will be shown: missing rows of a foot frame
are taken from that foot's previous frame; a foot frame that never came is
held (the foot's previous frame repeated) for up to ``HOLD_FRAMES`` slots,
then left as zeros. ``valid`` says what arrived whole, ``repaired`` what was
reconstructed; ``WindowDataset`` drops, by default, every window with an
input frame that is neither (a zero-filled foot: the daemon flags those
moments as degraded, they are no training material). The frame grid has one
slot per sequence number, so a window of T slots is always T/16 s long. A
gap of more than ``MAX_GAP`` sequence numbers with no frame and no label
(the daemon restarts its window there) starts a new segment instead of a
run of empty slots; windows never cross segments.

Decoded sessions are cached as ``.npz`` (keyed by path, size and mtime), so
repeated training runs do not decode again.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import tempfile
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from scotti.export.errors import ExportError
from scotti.firmware_protocol.assembly import FootFrame, FrameAssembler
from scotti.firmware_protocol.errors import SessionError
from scotti.firmware_protocol.framing import StreamDecoder
from scotti.firmware_protocol.packets import Foot, FrameRows
from scotti.firmware_protocol.session import find_session_files, read_session
from scotti.models import contract

log = logging.getLogger(__name__)

# Bump when the decoded arrays change meaning: old cache files are then ignored.
CACHE_VERSION = 3  # 3: progress NaN wherever the action has none (contract v2)
# What the daemon's pairing does live (models.contract), so training sees the same:
HOLD_FRAMES = contract.SILENT_FOOT_HOLD_FRAMES  # a missing foot frame: previous one, this long
MAX_GAP = contract.WINDOW_RESTART_GAP_FRAMES  # a longer run of empty slots: new segment
SEQ_MODULUS = 1 << 16


class TrainingDataError(ExportError):
    """A session or a split that cannot be used for training (one-line message)."""


@dataclass(frozen=True)
class SessionArrays:
    """One session on its sequence grid: N slots, one per (unwrapped) sequence number."""

    path: str
    subject: str
    frames: np.ndarray  # (N, H, 2W) uint16 counts, left foot columns 0..W-1, right W..2W-1
    valid: np.ndarray  # (N, 2) bool: that foot's frame arrived with all rows (left, right)
    repaired: np.ndarray  # (N, 2) bool: rows filled or frame held from the foot's previous
    seq: np.ndarray  # (N,) int64 unwrapped sequence number, +1 per slot within a segment
    segment: np.ndarray  # (N,) int32, increases at gaps longer than MAX_GAP
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


def unwrap_seq(raw: Sequence[int] | np.ndarray, reference: int | None = None) -> np.ndarray:
    """Wrapping u16 sequence numbers, in arrival order -> int64 timeline.

    Each number is placed at the signed wrap-aware distance from its
    predecessor (the first from ``reference``, an unwrapped value, if given).
    """
    r = np.asarray(raw, dtype=np.int64)
    if r.size == 0:
        return r
    steps = (np.diff(r) + SEQ_MODULUS // 2) % SEQ_MODULUS - SEQ_MODULUS // 2
    first = int(r[0])
    if reference is not None:
        delta = (first - reference + SEQ_MODULUS // 2) % SEQ_MODULUS - SEQ_MODULUS // 2
        first = reference + delta
    return first + np.concatenate([[0], np.cumsum(steps)])


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
    except (SessionError, OSError) as exc:
        msg = f"{path}: {exc}"
        raise TrainingDataError(msg) from None
    rows, cols = session.header.rows, session.header.cols
    counters: dict[str, int] = {
        "bad_records": session.bad_records + session.unknown_records,
        "truncated": int(session.truncated),
        "decode_errors": 0,
        "wrong_geometry": 0,
        "duplicate_frames": 0,
        "incomplete_frames": 0,
    }
    decoder = StreamDecoder()
    assembler = FrameAssembler()
    feet: dict[int, list[FootFrame]] = {int(Foot.LEFT): [], int(Foot.RIGHT): []}

    def collect(done: Iterable[FootFrame]) -> None:
        for ff in done:
            if ff.counts.shape != (rows, cols):
                counters["wrong_geometry"] += 1
                continue
            feet[int(ff.foot)].append(ff)

    for record in session.packets:
        for item in decoder.feed(record.data):
            if isinstance(item, FrameRows):
                collect(assembler.push(item, record.t_ns))
            elif isinstance(item, Exception):
                counters["decode_errors"] += 1
    collect(assembler.flush())

    labels = sorted(session.labels, key=lambda lab: lab.t_ns)
    return _to_grid(
        path=path,
        subject=subject_of(session.header.subject, path),
        rows=rows,
        cols=cols,
        feet=feet,
        labels=labels,
        counters=counters,
    )


def _to_grid(
    *,
    path: Path,
    subject: str,
    rows: int,
    cols: int,
    feet: dict[int, list[FootFrame]],
    labels: Sequence[Any],
    counters: dict[str, int],
) -> SessionArrays:
    # One timeline for both feet and the labels: the left foot's first frame
    # (or whatever came first) is the reference the others are unwrapped near.
    reference: int | None = None
    unwrapped: dict[int, np.ndarray] = {}
    for foot in (int(Foot.LEFT), int(Foot.RIGHT)):
        u = unwrap_seq([ff.seq for ff in feet[foot]], reference)
        unwrapped[foot] = u
        if reference is None and u.size:
            reference = int(u[0])
    label_seq = unwrap_seq([lab.seq for lab in labels], reference)
    every = np.concatenate([*unwrapped.values(), label_seq])
    if every.size == 0:
        msg = f"{path}: no foot frames and no labels in the session"
        raise TrainingDataError(msg)

    # The grid: consecutive sequence numbers, with gaps > MAX_GAP cut into segments.
    present = np.unique(every)
    breaks = np.flatnonzero(np.diff(present) > MAX_GAP) + 1
    pieces = np.split(present, breaks)
    seq = np.concatenate([np.arange(p[0], p[-1] + 1, dtype=np.int64) for p in pieces])
    segment = np.concatenate(
        [np.full(p[-1] - p[0] + 1, i, dtype=np.int32) for i, p in enumerate(pieces)]
    )
    n = seq.size

    frames = np.zeros((n, rows, 2 * cols), dtype=np.uint16)
    valid = np.zeros((n, 2), dtype=bool)
    seen = np.zeros((n, 2), dtype=bool)
    rows_missing: dict[tuple[int, int], np.ndarray] = {}
    for foot in (int(Foot.LEFT), int(Foot.RIGHT)):
        slots = np.searchsorted(seq, unwrapped[foot])
        c0 = foot * cols
        for ff, slot in zip(feet[foot], slots, strict=True):
            if seen[slot, foot]:
                counters["duplicate_frames"] += 1  # a reset or a repeat: keep the first
                continue
            seen[slot, foot] = True
            frames[slot, :, c0 : c0 + cols] = ff.counts
            complete = bool(ff.complete) and not bool(np.any(ff.rows_missing))
            if complete:
                valid[slot, foot] = True
            else:
                missing = np.asarray(ff.rows_missing, dtype=bool)
                frames[slot, missing, c0 : c0 + cols] = 0
                rows_missing[int(slot), foot] = missing
                counters["incomplete_frames"] += 1
    counters["missing_left"] = int(n - seen[:, 0].sum())
    counters["missing_right"] = int(n - seen[:, 1].sum())
    repaired = repair_like_the_daemon(frames, seen, rows_missing, segment, cols)
    counters["zero_filled"] = int((~(valid | repaired)).sum())

    has_label = np.zeros(n, dtype=bool)
    keypoints = np.full((n, contract.NUM_KEYPOINTS, 3), np.nan, dtype=np.float32)
    action = np.full(n, contract.NO_ACTION, dtype=np.int64)
    progress = np.full(n, np.nan, dtype=np.float32)
    bad_labels = 0
    for lab, slot in zip(labels, np.searchsorted(seq, label_seq), strict=True):
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


def repair_like_the_daemon(
    frames: np.ndarray,
    seen: np.ndarray,
    rows_missing: dict[tuple[int, int], np.ndarray],
    segment: np.ndarray,
    cols: int,
) -> np.ndarray:
    """Fill missing rows and hold missing feet in place; returns ``repaired`` (N, 2).

    ``frames`` (N, H, 2W) is changed in place. ``seen``: (N, 2) the foot frame
    arrived (whole or not); ``rows_missing``: the rows lost, per (slot, foot).
    """
    n = frames.shape[0]
    repaired = np.zeros((n, 2), dtype=bool)
    for foot in (int(Foot.LEFT), int(Foot.RIGHT)):
        c0 = foot * cols
        last: np.ndarray | None = None  # the foot's previous frame (repaired), a view
        missed = 0
        for slot in range(n):
            if slot and segment[slot] != segment[slot - 1]:
                last, missed = None, 0  # the daemon starts over after a long gap
            view = frames[slot, :, c0 : c0 + cols]
            if seen[slot, foot]:
                missing = rows_missing.get((slot, foot))
                if missing is not None and last is not None:
                    view[missing] = last[missing]
                    repaired[slot, foot] = True
                last, missed = view, 0
            else:
                missed += 1
                if last is not None and missed <= HOLD_FRAMES:
                    view[:] = last
                    repaired[slot, foot] = True
    return repaired


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
