"""Session files: the byte stream of one recording or simulation, plus labels.

Layout (all little endian)::

    # [magic:8 "SCOTSESS"] then records: [len:4 u32] [msgpack map: len bytes] ...

The first record is the header; packet and label records follow in the order
they were written. Each record goes to the OS in one write, so a writer
killed at any moment leaves a file whose last record at most is cut short;
readers stop at the last whole record and report ``truncated``.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import IO, Any, Final, Literal, Self, TypeAlias

import msgpack
import numpy as np
from scotti.firmware_protocol.errors import SessionError
from scotti.firmware_protocol.packets import DEFAULT_COLS, DEFAULT_ROWS, DEFAULT_SAMPLE_BITS

MAGIC: Final = b"SCOTSESS"  # first 8 bytes of every session file
FORMAT_VERSION: Final = 1  # "format_version" of the header; readers refuse newer ones
LEN_BYTES: Final = 4  # record length prefix, u32 little endian
MAX_RECORD_LEN: Final = 16 << 20  # a longer length prefix means corruption, not data
NUM_KEYPOINTS: Final = 19  # label keypoints (equals models.contract.NUM_KEYPOINTS)
KEYPOINTS_BYTES: Final = NUM_KEYPOINTS * 3 * 4  # float32 (19, 3), little endian
SOURCES: Final = ("recorded", "simulated", "imported")  # allowed header "source" values

Source: TypeAlias = Literal["recorded", "simulated", "imported"]
_BAD_RECORD: Final[dict[str, Any]] = {}  # stands for a whole record that did not decode


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


Record: TypeAlias = SessionHeader | PacketRecord | LabelRecord | SourceFrameRecord


def _pack(record: dict[str, Any]) -> bytes:
    try:
        body = msgpack.packb(record, use_bin_type=True)
    except (TypeError, ValueError, OverflowError) as exc:
        msg = f"cannot store a {record.get('kind')} record in a session file: {exc}"
        raise SessionError(msg) from None
    return len(body).to_bytes(LEN_BYTES, "little") + body


class _ClosedOnExit:
    """``with`` support for the writer and the reader: ``close()`` on the way out."""

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


class SessionWriter(_ClosedOnExit):
    """Appends records to a new session file; one OS write and flush per record.

    ``fsync_interval_s``: also fsync when that long has passed since the last
    one (None: only on close). ``flush_each``: False trades kill -9 safety for
    speed (the simulator writing a large file). An existing file at ``path``
    is a ``SessionError`` unless ``overwrite`` says to replace it.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        header: SessionHeader,
        *,
        fsync_interval_s: float | None = None,
        flush_each: bool = True,
        overwrite: bool = False,
    ) -> None:
        self.path = Path(path)
        self.header = header
        self.records = 0
        self._fsync_interval_s = fsync_interval_s
        self._flush_each = flush_each
        self._last_fsync = time.monotonic()
        mode = "wb" if overwrite else "xb"  # "x": never replace a recording by accident
        try:
            self._file: IO[bytes] | None = open(self.path, mode)  # noqa: SIM115  # closed in close()
        except FileExistsError:
            msg = f"session file {self.path} exists; refusing to overwrite"
            raise SessionError(msg) from None
        except OSError as exc:
            msg = f"cannot create session file {self.path}: {exc.strerror}"
            raise SessionError(msg) from None
        try:
            self._file.write(MAGIC)
            self._write(header.to_record())
        except BaseException:
            self._file.close()
            self._file = None
            raise

    def write_packet(self, t_ns: int, data: bytes) -> None:
        self._write(PacketRecord(t_ns, bytes(data)).to_record())

    def write_label(self, label: LabelRecord) -> None:
        self._write(label.to_record())

    def write(self, record: PacketRecord | LabelRecord | SourceFrameRecord) -> None:
        self._write(record.to_record())

    def flush(self) -> None:
        if self._file is not None:
            self._file.flush()

    def fsync(self) -> None:
        if self._file is not None:
            self._file.flush()
            os.fsync(self._file.fileno())
            self._last_fsync = time.monotonic()

    def close(self) -> None:
        if self._file is None:
            return
        try:
            self.fsync()
        finally:
            self._file.close()
            self._file = None

    def _write(self, record: dict[str, Any]) -> None:
        if self._file is None:
            msg = f"session file {self.path} is closed"
            raise SessionError(msg)
        data = _pack(record)
        try:
            self._file.write(data)  # length and body in one write
            if self._flush_each:
                self._file.flush()
            interval = self._fsync_interval_s
            if interval is not None and time.monotonic() - self._last_fsync >= interval:
                self.fsync()
        except OSError as exc:
            msg = f"cannot write session file {self.path}: {exc.strerror}"
            raise SessionError(msg) from None
        self.records += 1


class SessionReader(_ClosedOnExit):
    """Streams the records of a session file; the header is read on open.

    Iterating yields ``PacketRecord`` and ``LabelRecord`` in file order (and
    ``SourceFrameRecord`` when ``source_frames`` is set; skipped otherwise). When
    it ends, ``truncated`` says whether the file stopped inside a record,
    ``bad_records`` how many whole records could not be understood and
    ``unknown_records`` how many had a kind this reader does not know.
    """

    def __init__(self, path: str | os.PathLike[str], *, source_frames: bool = False) -> None:
        self.path = Path(path)
        self.source_frames = source_frames
        self.truncated = False
        self.bad_records = 0
        self.unknown_records = 0
        self.bytes_read = 0
        try:
            self._file: IO[bytes] = open(self.path, "rb")  # noqa: SIM115  # closed in close()
        except OSError as exc:
            msg = f"cannot open session file {self.path}: {exc.strerror}"
            raise SessionError(msg) from None
        try:
            self.header = self._read_header()
        except BaseException:
            self._file.close()
            raise

    def _read_header(self) -> SessionHeader:
        magic = self._file.read(len(MAGIC))
        self.bytes_read = len(magic)
        if magic != MAGIC:
            if MAGIC.startswith(magic) and magic:
                msg = f"{self.path} is a session file cut short before its header"
            else:
                msg = f"{self.path} is not a session file (no {MAGIC.decode()} magic)"
            raise SessionError(msg)
        record = self._next_map()
        if record is None:
            msg = f"{self.path} is a session file cut short before its header"
            raise SessionError(msg)
        if record.get("kind") != "header":
            msg = f"{self.path} has no header record (first record is {record.get('kind')!r})"
            raise SessionError(msg)
        return SessionHeader.from_record(record)

    def _next_map(self) -> dict[str, Any] | None:
        """The next whole record, ``_BAD_RECORD`` if it does not decode, None at the end."""
        prefix = self._file.read(LEN_BYTES)
        if len(prefix) < LEN_BYTES:
            self.truncated = bool(prefix)
            return None
        length = int.from_bytes(prefix, "little")
        if length == 0 or length > MAX_RECORD_LEN:
            msg = f"{self.path} is corrupt: record of {length} bytes at offset {self.bytes_read}"
            raise SessionError(msg)
        body = self._file.read(length)
        if len(body) < length:
            self.truncated = True
            return None
        self.bytes_read += LEN_BYTES + length
        try:
            record = msgpack.unpackb(body, raw=False)
        except (ValueError, TypeError, msgpack.UnpackException):
            self.bad_records += 1
            return _BAD_RECORD
        if not isinstance(record, dict):
            self.bad_records += 1
            return _BAD_RECORD
        return record

    def __iter__(self) -> Iterator[PacketRecord | LabelRecord]:
        for record in self.records():
            if not isinstance(record, SourceFrameRecord):
                yield record

    def records(self) -> Iterator[PacketRecord | LabelRecord | SourceFrameRecord]:
        """Every whole record after the header, source frames when asked for."""
        while (record := self._next_map()) is not None:
            kind = record.get("kind")
            try:
                if kind == "packet":
                    yield PacketRecord.from_record(record)
                elif kind == "label":
                    yield LabelRecord.from_record(record)
                elif kind == "source_frame":
                    if self.source_frames:
                        yield SourceFrameRecord.from_record(record)
                elif record is _BAD_RECORD:
                    pass  # already counted by _next_map
                elif not isinstance(kind, str):
                    self.bad_records += 1
                else:
                    self.unknown_records += 1  # a newer writer's record kind: skipped
            except (KeyError, TypeError, ValueError, SessionError):
                self.bad_records += 1

    def close(self) -> None:
        self._file.close()


@dataclass
class Session:
    """A whole session file in memory."""

    header: SessionHeader
    packets: list[PacketRecord]
    labels: list[LabelRecord]
    truncated: bool = False  # the file ends inside a record (writer killed, power lost)
    bad_records: int = 0  # whole records that could not be understood (skipped)
    unknown_records: int = 0  # records of a kind this reader does not know (skipped)


def read_session(path: str | os.PathLike[str]) -> Session:
    """Read every whole record of a session file; raises ``SessionError`` (one line)."""
    packets: list[PacketRecord] = []
    labels: list[LabelRecord] = []
    with SessionReader(path) as reader:
        for record in reader:
            if isinstance(record, PacketRecord):
                packets.append(record)
            else:
                labels.append(record)
    return Session(
        reader.header, packets, labels, reader.truncated, reader.bad_records, reader.unknown_records
    )


def iter_records(path: str | os.PathLike[str], *, source_frames: bool = False) -> Iterator[Record]:
    """Stream the header, then every whole packet and label record, in file order.

    ``source_frames``: also an imported session's source frames, where they lie.
    """
    with SessionReader(path, source_frames=source_frames) as reader:
        yield reader.header
        yield from reader.records()


def find_session_files(paths: Iterable[str | os.PathLike[str]]) -> list[Path]:
    """Files as given, plus every session file (by its magic) under directories.

    Raises ``SessionError`` (one line) for a path that does not exist, or when
    nothing at all was found.
    """
    paths = list(paths)
    found: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            found.extend(f for f in sorted(p.rglob("*")) if f.is_file() and _is_session(f))
        elif p.is_file():
            found.append(p)
        else:
            msg = f"{p}: no such file or directory"
            raise SessionError(msg)
    if not found:
        msg = "no session files found in " + ", ".join(map(str, paths))
        raise SessionError(msg)
    return found


def _is_session(path: Path) -> bool:
    try:
        with path.open("rb") as f:
            return f.read(len(MAGIC)) == MAGIC
    except OSError:
        return False
