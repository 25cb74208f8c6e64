"""The records of a session file: header, packets as received, labels, source frames,
marked events.

Each is a frozen dataclass with ``to_record`` / ``from_record`` to and from
the msgpack map stored in the file; :mod:`scotti.firmware_protocol.session`
frames, writes and reads them.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Final, Literal, TypeAlias

import numpy as np
from scotti.firmware_protocol.errors import SessionError
from scotti.firmware_protocol.packets import DEFAULT_COLS, DEFAULT_ROWS, DEFAULT_SAMPLE_BITS

FORMAT_VERSION: Final = 1  # "format_version" of the header; readers refuse newer ones
NUM_KEYPOINTS: Final = 19  # label keypoints (equals models.contract.NUM_KEYPOINTS)
KEYPOINTS_BYTES: Final = NUM_KEYPOINTS * 3 * 4  # float32 (19, 3), little endian
SOURCES: Final = ("recorded", "simulated", "imported")  # allowed header "source" values

Source: TypeAlias = Literal["recorded", "simulated", "imported"]


@dataclass(frozen=True)
class SessionHeader:
    """First record of every session file."""

    source: Source
    device: str = "scotti"
    rows: int = DEFAULT_ROWS
    cols: int = DEFAULT_COLS
    sample_bits: int = DEFAULT_SAMPLE_BITS
    rate_hz: float = 16.0
    created_unix: float = field(default_factory=time.time)
    scene: dict[str, Any] | None = None  # the scene a simulated session was made from
    subject: dict[str, Any] | None = None  # who wore the insoles (simulated or recorded)
    format_version: int = FORMAT_VERSION
    # An imported session's provenance: source files, their grid and rate, the
    # mapping onto the contract (importers/IMPORT.md). None for the others.
    imported: dict[str, Any] | None = None

    def __post_init__(self) -> None:
        if self.source not in SOURCES:
            msg = f"session source {self.source!r} is not one of {', '.join(SOURCES)}"
            raise SessionError(msg)

    def to_record(self) -> dict[str, Any]:
        record = {
            "kind": "header",
            "format_version": self.format_version,
            "source": self.source,
            "device": self.device,
            "rows": self.rows,
            "cols": self.cols,
            "sample_bits": self.sample_bits,
            "rate_hz": float(self.rate_hz),
            "created_unix": float(self.created_unix),
            "scene": self.scene,
            "subject": self.subject,
        }
        if self.imported is not None:  # only imported files carry it: others stay as they were
            record["imported"] = self.imported
        return record

    @classmethod
    def from_record(cls, record: dict[str, Any]) -> SessionHeader:
        version = record.get("format_version")
        if not isinstance(version, int) or version > FORMAT_VERSION or version < 1:
            msg = f"session format_version {version!r}; this reader reads 1..{FORMAT_VERSION}"
            raise SessionError(msg)
        try:
            return cls(
                source=record["source"],
                device=str(record["device"]),
                rows=int(record["rows"]),
                cols=int(record["cols"]),
                sample_bits=int(record["sample_bits"]),
                rate_hz=float(record["rate_hz"]),
                created_unix=float(record["created_unix"]),
                scene=record.get("scene"),
                subject=record.get("subject"),
                format_version=version,
                imported=record.get("imported"),
            )
        except (KeyError, TypeError, ValueError) as exc:
            msg = f"session header is incomplete or malformed ({exc!r})"
            raise SessionError(msg) from None


@dataclass(frozen=True)
class PacketRecord:
    """Bytes as they came off the port (any chunking, garbage included)."""

    t_ns: int  # host monotonic time when the chunk was read
    data: bytes

    def to_record(self) -> dict[str, Any]:
        return {"kind": "packet", "t_ns": self.t_ns, "data": self.data}

    @classmethod
    def from_record(cls, record: dict[str, Any]) -> PacketRecord:
        t_ns, data = record["t_ns"], record["data"]
        if not isinstance(t_ns, int) or not isinstance(data, bytes):
            msg = "packet record needs int t_ns and bytes data"
            raise TypeError(msg)
        return cls(t_ns, data)


@dataclass(frozen=True, eq=False)
class LabelRecord:
    """Ground truth for the foot frames with sequence ``seq`` (both feet)."""

    seq: int  # the u16 foot-frame sequence number this label belongs to
    t_ns: int  # host monotonic time of that frame
    keypoints: np.ndarray = field(repr=False)  # (19, 3) float32 metres, pose frame
    action: int = -1  # index into models.contract.ACTIONS, -1 (NO_ACTION): a transition
    progress: float = float("nan")  # 0..1 through the repetition, NaN where undefined (standing)
    rep: int = -1  # repetition count within the action, -1 when none

    def __post_init__(self) -> None:
        keypoints = np.asarray(self.keypoints, dtype=np.float32)
        if keypoints.shape != (NUM_KEYPOINTS, 3):
            msg = f"label keypoints must be ({NUM_KEYPOINTS}, 3), got {keypoints.shape}"
            raise SessionError(msg)
        object.__setattr__(self, "keypoints", keypoints)

    def to_record(self) -> dict[str, Any]:
        return {
            "kind": "label",
            "seq": self.seq,
            "t_ns": self.t_ns,
            "keypoints": self.keypoints.astype("<f4").tobytes(),
            "action": self.action,
            "progress": float(self.progress),
            "rep": self.rep,
        }

    @classmethod
    def from_record(cls, record: dict[str, Any]) -> LabelRecord:
        raw = record["keypoints"]
        if not isinstance(raw, bytes) or len(raw) != KEYPOINTS_BYTES:
            msg = f"label keypoints must be {KEYPOINTS_BYTES} bytes"
            raise ValueError(msg)
        keypoints = np.frombuffer(raw, dtype="<f4").reshape(NUM_KEYPOINTS, 3)
        return cls(
            seq=int(record["seq"]),
            t_ns=int(record["t_ns"]),
            keypoints=keypoints.astype(np.float32),
            action=int(record["action"]),
            progress=float(record["progress"]),
            rep=int(record.get("rep", -1)),
        )

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, LabelRecord):
            return NotImplemented
        mine = (self.seq, self.t_ns, self.action, self.rep)
        same_progress = self.progress == other.progress or (
            np.isnan(self.progress) and np.isnan(other.progress)
        )
        return (
            mine == (other.seq, other.t_ns, other.action, other.rep)
            and bool(same_progress)
            and np.array_equal(self.keypoints, other.keypoints)
        )

    __hash__ = None  # type: ignore[assignment]  # holds an array: not hashable


@dataclass(frozen=True, eq=False)
class SourceFrameRecord:
    """An imported session's pressure as its source stored it, before resampling.

    Kept (thinned) so pictures can show the original grid beside the 32 x 22
    one; readers skip these unless asked (``SessionReader(source_frames=True)``).
    """

    t_ns: int  # the source's own time stamp of this frame
    frames: np.ndarray = field(repr=False)  # (2, rows, cols) float32, left then right, as stored

    def __post_init__(self) -> None:
        frames = np.asarray(self.frames, dtype=np.float32)
        if frames.ndim != 3 or frames.shape[0] != 2:
            msg = f"source frames must be (2, rows, cols), got {frames.shape}"
            raise SessionError(msg)
        object.__setattr__(self, "frames", frames)

    def to_record(self) -> dict[str, Any]:
        _, rows, cols = self.frames.shape
        data = self.frames.astype("<f4").tobytes()
        return {"kind": "source_frame", "t_ns": self.t_ns, "rows": rows, "cols": cols, "data": data}

    @classmethod
    def from_record(cls, record: dict[str, Any]) -> SourceFrameRecord:
        rows, cols, raw = int(record["rows"]), int(record["cols"]), record["data"]
        if not isinstance(raw, bytes) or len(raw) != 2 * rows * cols * 4:
            msg = f"source frame data must be 2 x {rows} x {cols} float32"
            raise ValueError(msg)
        frames = np.frombuffer(raw, dtype="<f4").reshape(2, rows, cols).astype(np.float32)
        return cls(t_ns=int(record["t_ns"]), frames=frames)


@dataclass(frozen=True)
class EventRecord:
    """A moment marked while recording (``event/mark`` over MQTT): a label, a detail.

    Written beside the packets it happened among; readers that predate it skip it
    as a record of unknown kind, and readers skip it unless asked
    (``SessionReader(events=True)``), so replay and evaluation never see it.
    """

    t_ns: int  # host monotonic time, the packet records' clock
    label: str
    detail: str = ""
    wall_ns: int = 0  # host wall clock (Unix ns) when it was marked

    def to_record(self) -> dict[str, Any]:
        return {
            "kind": "mark",
            "t_ns": self.t_ns,
            "wall_ns": self.wall_ns,
            "label": self.label,
            "detail": self.detail,
        }

    @classmethod
    def from_record(cls, record: dict[str, Any]) -> EventRecord:
        t_ns, wall_ns = record["t_ns"], record.get("wall_ns", 0)
        label, detail = record["label"], record.get("detail", "")
        if not isinstance(t_ns, int) or not isinstance(wall_ns, int):
            msg = "event record needs int t_ns and wall_ns"
            raise TypeError(msg)
        if not isinstance(label, str) or not isinstance(detail, str):
            msg = "event record needs text label and detail"
            raise TypeError(msg)
        return cls(t_ns, label, detail, wall_ns)


Record: TypeAlias = SessionHeader | PacketRecord | LabelRecord | SourceFrameRecord | EventRecord
