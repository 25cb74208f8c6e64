"""Session files: the byte stream of one recording or simulation, plus labels.

Layout (all little endian)::

    # [magic:8 "SCOTSESS"] then records: [len:4 u32] [msgpack map: len bytes] ...

The first record is the header; packet and label records follow in the order
they were written. Each record, or each batch of whole records
(``SessionWriter.write_many``), goes to the OS in one write, so a writer
killed at any moment leaves a file whose last record at most is cut short;
readers stop at the last whole record and report ``truncated``.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import IO, Any, Final, Self

import msgpack
from scotti.firmware_protocol.errors import SessionError
from scotti.firmware_protocol.session_records import FORMAT_VERSION as FORMAT_VERSION
from scotti.firmware_protocol.session_records import KEYPOINTS_BYTES as KEYPOINTS_BYTES
from scotti.firmware_protocol.session_records import NUM_KEYPOINTS as NUM_KEYPOINTS
from scotti.firmware_protocol.session_records import SOURCES as SOURCES
from scotti.firmware_protocol.session_records import EventRecord as EventRecord
from scotti.firmware_protocol.session_records import LabelRecord as LabelRecord
from scotti.firmware_protocol.session_records import PacketRecord as PacketRecord
from scotti.firmware_protocol.session_records import Record as Record
from scotti.firmware_protocol.session_records import SessionHeader as SessionHeader
from scotti.firmware_protocol.session_records import Source as Source
from scotti.firmware_protocol.session_records import SourceFrameRecord as SourceFrameRecord
from scotti.firmware_protocol.session_unpack import MAX_RECORD_LEN as MAX_RECORD_LEN
from scotti.firmware_protocol.session_unpack import (
    OverLimitError,
    UndecodableError,
    check_shape,
    unpack_record,
)

MAGIC: Final = b"SCOTSESS"  # first 8 bytes of every session file
LEN_BYTES: Final = 4  # record length prefix, u32 little endian

_BAD_RECORD: Final[dict[str, Any]] = {}  # stands for a whole record that did not decode


def _pack(record: dict[str, Any], packer: msgpack.Packer | None = None) -> bytes:
    """The record's body in msgpack; ``packer`` (one made with ``use_bin_type``) saves
    making one per record and packs the same bytes."""
    try:
        body = msgpack.packb(record, use_bin_type=True) if packer is None else packer.pack(record)
    except (TypeError, ValueError, OverflowError) as exc:
        msg = f"cannot store a {record.get('kind')} record in a session file: {exc}"
        raise SessionError(msg) from None
    if len(body) > MAX_RECORD_LEN:  # readers would refuse the file
        kind, size = record.get("kind"), len(body)
        msg = f"cannot store a {kind} record of {size} bytes (at most {MAX_RECORD_LEN})"
        raise SessionError(msg)
    return body


def _check_storable(record: dict[str, Any]) -> None:
    """A header whose scene, subject or provenance no reader would take: ``SessionError``
    (the other records are flat maps of known size)."""
    try:
        check_shape(_pack(record))
    except OverLimitError as exc:
        msg = f"cannot store a {record.get('kind')} record in a session file: {exc.what}"
        raise SessionError(msg) from None


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
    """Appends records to a new session file; one OS write and flush per record
    (per batch with ``write_many``).

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
            record = header.to_record()
            _check_storable(record)
            self._write(record)
        except BaseException:
            self._file.close()
            self._file = None
            raise

    def write_packet(self, t_ns: int, data: bytes) -> None:
        self._write(PacketRecord(t_ns, bytes(data)).to_record())

    def write_label(self, label: LabelRecord) -> None:
        self._write(label.to_record())

    def write(self, record: PacketRecord | LabelRecord | SourceFrameRecord | EventRecord) -> None:
        self._write(record.to_record())

    def write_many(
        self, records: Iterable[PacketRecord | LabelRecord | SourceFrameRecord | EventRecord]
    ) -> None:
        """Append records in one OS write: the bytes ``write`` gives for each in turn.

        For writers of a whole file at once (the importer), where a write, and a
        packer, per record cost more than the packing. Every record is packed before
        any is written, so one that cannot be stored (``SessionError``) writes none.
        """
        self._open_file()
        packer = msgpack.Packer(use_bin_type=True)
        buffer = bytearray()
        count = 0
        for record in records:
            body = _pack(record.to_record(), packer)
            buffer += len(body).to_bytes(LEN_BYTES, "little")
            buffer += body
            count += 1
        if count:
            self._put(buffer, count)

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

    def _open_file(self) -> IO[bytes]:
        if self._file is None:
            msg = f"session file {self.path} is closed"
            raise SessionError(msg)
        return self._file

    def _write(self, record: dict[str, Any]) -> None:
        self._open_file()
        body = _pack(record)
        self._put(len(body).to_bytes(LEN_BYTES, "little") + body, 1)

    def _put(self, data: bytes | bytearray, records: int) -> None:
        """Hand ``data``, ``records`` whole records, to the OS in one write."""
        file = self._open_file()
        try:
            file.write(data)  # lengths and bodies in one write
            if self._flush_each:
                file.flush()
            interval = self._fsync_interval_s
            if interval is not None and time.monotonic() - self._last_fsync >= interval:
                self.fsync()
        except OSError as exc:
            msg = f"cannot write session file {self.path}: {exc.strerror}"
            raise SessionError(msg) from None
        self.records += records


class SessionReader(_ClosedOnExit):
    """Streams the records of a session file; the header is read on open.

    Iterating yields ``PacketRecord`` and ``LabelRecord`` in file order (and
    ``SourceFrameRecord`` when ``source_frames`` is set, ``EventRecord`` when ``events``
    is; skipped otherwise). When
    it ends, ``truncated`` says whether the file stopped inside a record,
    ``bad_records`` how many whole records could not be understood and
    ``unknown_records`` how many had a kind this reader does not know.
    """

    def __init__(
        self, path: str | os.PathLike[str], *, source_frames: bool = False, events: bool = False
    ) -> None:
        self.path = Path(path)
        self.source_frames = source_frames
        self.events = events
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
            self._size = os.fstat(self._file.fileno()).st_size
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
        try:
            return SessionHeader.from_record(record)
        except SessionError as exc:  # every error of a reader names its file
            raise SessionError(f"{self.path}: {exc}") from None

    def _next_map(self) -> dict[str, Any] | None:
        """The next whole record, ``_BAD_RECORD`` if it does not decode, None at the end.

        Nothing is allocated for a record before its length is checked against the
        largest record and the bytes the file holds, and it is unpacked within
        limits (``unpack_record``): a record over them is a ``SessionError``.
        """
        offset = self.bytes_read
        prefix = self._file.read(LEN_BYTES)
        if len(prefix) < LEN_BYTES:
            self.truncated = bool(prefix)
            return None
        length = int.from_bytes(prefix, "little")
        if length == 0 or length > MAX_RECORD_LEN:
            msg = f"{self.path} is corrupt: record of {length} bytes at offset {offset}"
            raise SessionError(msg)
        end = offset + LEN_BYTES + length
        if end > self._size and not self._holds(end):
            self.truncated = True  # cut inside this record, or its length is damaged
            return None
        body = self._file.read(length)
        if len(body) < length:  # the file shrank under us
            self.truncated = True
            return None
        self.bytes_read += LEN_BYTES + length
        try:
            return unpack_record(body)
        except OverLimitError as exc:
            at = offset + LEN_BYTES + exc.at
            msg = f"{self.path} is corrupt at byte {at}: {exc.what} in the record at {offset}"
            raise SessionError(msg) from None
        except UndecodableError:
            self.bad_records += 1
            return _BAD_RECORD

    def _holds(self, end: int) -> bool:
        """Whether the file is at least ``end`` bytes long (one still being written grows)."""
        if end <= self._size:
            return True
        self._size = os.fstat(self._file.fileno()).st_size
        return end <= self._size

    def __iter__(self) -> Iterator[PacketRecord | LabelRecord]:
        for record in self.records():
            if not isinstance(record, SourceFrameRecord | EventRecord):
                yield record

    def records(self) -> Iterator[PacketRecord | LabelRecord | SourceFrameRecord | EventRecord]:
        """Every whole record after the header, source frames and events when asked for."""
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
                elif kind == "mark":  # an EventRecord
                    if self.events:
                        yield EventRecord.from_record(record)
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


def iter_records(
    path: str | os.PathLike[str], *, source_frames: bool = False, events: bool = False
) -> Iterator[Record]:
    """Stream the header, then every whole packet and label record, in file order.

    ``source_frames``: also an imported session's source frames, where they lie;
    ``events``: also the events marked while recording.
    """
    with SessionReader(path, source_frames=source_frames, events=events) as reader:
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
