"""Session files: round trip, a cut at every byte, corruption, a killed writer."""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
from pathlib import Path

import msgpack
import numpy as np
import pytest
from scotti.firmware_protocol.errors import SessionError
from scotti.firmware_protocol.session import (
    MAGIC,
    EventRecord,
    LabelRecord,
    PacketRecord,
    SessionHeader,
    SessionReader,
    SessionWriter,
    SourceFrameRecord,
    find_session_files,
    iter_records,
    read_session,
)
from scotti.models import contract

HEADER = SessionHeader(
    source="simulated", device="test-rig", created_unix=1.7e9, scene={"name": "squats", "seed": 3}
)


def label(seq: int, action: int = 0) -> LabelRecord:
    keypoints = np.arange(57, dtype=np.float32).reshape(19, 3) / 10 + seq
    progress = math.nan if action < 0 else 0.25
    return LabelRecord(seq, 1000 * seq, keypoints, action, progress, rep=-1 if action < 0 else 2)


def write_small(path: Path, *, bulk: bool = False) -> list[PacketRecord | LabelRecord]:
    """A few records, one ``write`` each or (``bulk``) in one ``write_many``."""
    records: list[PacketRecord | LabelRecord] = [
        PacketRecord(10, b"\x01\x02\x00"),
        label(0),
        PacketRecord(20, bytes(range(256))),
        label(1, action=-1),
        PacketRecord(30, b""),
    ]
    with SessionWriter(path, HEADER) as writer:
        if bulk:
            writer.write_many(records)
        else:
            for record in records:
                writer.write(record)
    return records


def test_constants_agree_with_the_model_contract() -> None:
    assert (HEADER.rows, HEADER.cols, HEADER.sample_bits) == (
        contract.FRAME_ROWS,
        contract.FRAME_COLS,
        contract.SAMPLE_BITS,
    )
    assert label(0).keypoints.shape == (contract.NUM_KEYPOINTS, 3)


def test_round_trip(tmp_path: Path) -> None:
    path = tmp_path / "s.scot"
    records = write_small(path)
    session = read_session(path)
    assert session.header == HEADER
    assert session.packets == [r for r in records if isinstance(r, PacketRecord)]
    assert session.labels == [r for r in records if isinstance(r, LabelRecord)]
    assert session.labels[0].keypoints.dtype == np.float32
    assert math.isnan(session.labels[1].progress)
    assert (session.truncated, session.bad_records) == (False, 0)
    assert list(iter_records(path)) == [HEADER, *records]


def test_file_layout_is_magic_then_length_prefixed_msgpack(tmp_path: Path) -> None:
    path = tmp_path / "s.scot"
    write_small(path)
    raw = path.read_bytes()
    assert raw.startswith(MAGIC)
    length = int.from_bytes(raw[8:12], "little")
    header = msgpack.unpackb(raw[12 : 12 + length])
    assert header["kind"] == "header"
    assert header["format_version"] == 1
    assert header["scene"] == {"name": "squats", "seed": 3}
    length2 = int.from_bytes(raw[12 + length : 16 + length], "little")
    first = msgpack.unpackb(raw[16 + length : 16 + length + length2])
    assert first == {"kind": "packet", "t_ns": 10, "data": b"\x01\x02\x00"}


def record_ends(raw: bytes) -> list[int]:
    """Offsets at which each whole record (header first) ends."""
    ends, offset = [], len(MAGIC)
    while offset < len(raw):
        offset += 4 + int.from_bytes(raw[offset : offset + 4], "little")
        ends.append(offset)
    return ends


@pytest.mark.parametrize("bulk", [False, True])
def test_cut_at_every_byte_reads_every_whole_record(tmp_path: Path, bulk: bool) -> None:
    full = tmp_path / "full.scot"
    records = write_small(full, bulk=bulk)
    raw = full.read_bytes()
    ends = record_ends(raw)
    cut = tmp_path / "cut.scot"
    for size in range(len(raw)):
        cut.write_bytes(raw[:size])
        if size < ends[0]:
            with pytest.raises(SessionError, match=r"cut short before its header|not a session"):
                read_session(cut)
            continue
        session = read_session(cut)
        whole = sum(1 for end in ends[1:] if end <= size)
        expected = records[:whole]
        assert session.packets == [r for r in expected if isinstance(r, PacketRecord)]
        assert session.labels == [r for r in expected if isinstance(r, LabelRecord)]
        assert session.truncated == (size not in ends), size


@pytest.mark.parametrize(
    ("content", "words"),
    [
        (b"", "not a session file"),
        (b"hello world, not a session", "not a session file"),
        (MAGIC[:5], "cut short before its header"),
        (MAGIC + b"\xff\xff\xff\xff" + b"x" * 100, "corrupt: record of 4294967295 bytes"),
        (MAGIC + b"\x00\x00\x00\x00", "corrupt: record of 0 bytes"),
    ],
)
def test_bad_files_give_one_line_errors(tmp_path: Path, content: bytes, words: str) -> None:
    path = tmp_path / "bad.scot"
    path.write_bytes(content)
    with pytest.raises(SessionError, match=words) as caught:
        read_session(path)
    assert "\n" not in str(caught.value)


def raw_record(record: object) -> bytes:
    body = msgpack.packb(record)
    return len(body).to_bytes(4, "little") + body


def test_missing_header_record(tmp_path: Path) -> None:
    path = tmp_path / "noheader.scot"
    path.write_bytes(MAGIC + raw_record({"kind": "packet", "t_ns": 1, "data": b""}))
    with pytest.raises(SessionError, match="no header record"):
        read_session(path)


def test_newer_format_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "new.scot"
    path.write_bytes(MAGIC + raw_record({**HEADER.to_record(), "format_version": 2}))
    with pytest.raises(SessionError, match="format_version 2"):
        read_session(path)


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(SessionError, match="cannot open"):
        read_session(tmp_path / "nope.scot")


def test_bad_and_unknown_records_are_skipped_and_counted(tmp_path: Path) -> None:
    path = tmp_path / "odd.scot"
    path.write_bytes(
        MAGIC
        + raw_record(HEADER.to_record())
        + raw_record({"kind": "event", "what": "from a newer writer"})
        + raw_record({"kind": "packet", "t_ns": "soon"})
        + b"\x03\x00\x00\x00\xc1\xc1\xc1"  # a length-correct record that is not msgpack
        + raw_record([1, 2, 3])
        + raw_record({"kind": "label", "seq": 1, "t_ns": 0, "keypoints": b"short"})
        + raw_record({"kind": "packet", "t_ns": 5, "data": b"ok"})
    )
    session = read_session(path)
    assert session.packets == [PacketRecord(5, b"ok")]
    assert (session.bad_records, session.unknown_records) == (4, 1)
    assert not session.truncated


def test_header_validates_source() -> None:
    with pytest.raises(SessionError, match="source"):
        SessionHeader(source="dreamed")  # type: ignore[arg-type]


def test_writer_refuses_writes_after_close_and_bad_paths(tmp_path: Path) -> None:
    writer = SessionWriter(tmp_path / "a.scot", HEADER, fsync_interval_s=0.0)
    writer.write_packet(1, b"x")
    writer.close()
    writer.close()
    with pytest.raises(SessionError, match="closed"):
        writer.write_packet(2, b"y")
    with pytest.raises(SessionError, match="cannot create"):
        SessionWriter(tmp_path / "missing-dir" / "a.scot", HEADER)


def test_find_session_files_by_magic_and_bad_paths(tmp_path: Path) -> None:
    (tmp_path / "b").mkdir()
    (tmp_path / "empty").mkdir()
    write_small(tmp_path / "a.scot")
    write_small(tmp_path / "b" / "x.anything")
    (tmp_path / "b" / "notes.txt").write_text("not a session")
    (tmp_path / "b" / "cut").write_bytes(MAGIC[:4])
    given = tmp_path / "b" / "notes.txt"  # a file named explicitly is taken as it is
    found = find_session_files([tmp_path, given])
    names = [p.relative_to(tmp_path).as_posix() for p in found]
    assert names == ["a.scot", "b/x.anything", "b/notes.txt"]
    with pytest.raises(SessionError, match=r"missing: no such file or directory$"):
        find_session_files([tmp_path / "missing"])
    with pytest.raises(SessionError, match=r"^no session files found in .*empty$"):
        find_session_files([tmp_path / "empty"])


def test_writer_refuses_an_existing_file_unless_told_to_overwrite(tmp_path: Path) -> None:
    path = tmp_path / "a.scot"
    write_small(path)
    before = path.read_bytes()
    with pytest.raises(SessionError, match=r"a\.scot exists; refusing to overwrite$"):
        SessionWriter(path, HEADER)
    assert path.read_bytes() == before
    with SessionWriter(path, HEADER, overwrite=True) as writer:
        writer.write_packet(5, b"new")
    assert read_session(path).packets == [PacketRecord(5, b"new")]


def test_reader_streams_with_counters(tmp_path: Path) -> None:
    path = tmp_path / "s.scot"
    write_small(path)
    path.write_bytes(path.read_bytes()[:-3])
    with SessionReader(path) as reader:
        kinds = [type(r).__name__ for r in reader]
    assert kinds == ["PacketRecord", "LabelRecord", "PacketRecord", "LabelRecord"]
    assert reader.truncated


_KILLED_WRITER = """
import sys, time
from scotti.firmware_protocol.session import SessionHeader, SessionWriter
writer = SessionWriter(sys.argv[1], SessionHeader(source="recorded"))
for i in range(10**9):
    writer.write_packet(i, bytes(1000))
    if i == 200:
        print("ready", flush=True)
"""


def test_writer_killed_by_sigkill_leaves_a_readable_file(tmp_path: Path) -> None:
    path = tmp_path / "killed.scot"
    proc = subprocess.Popen(
        [sys.executable, "-c", _KILLED_WRITER, str(path)], stdout=subprocess.PIPE
    )
    assert proc.stdout is not None
    assert proc.stdout.readline() == b"ready\n"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=10)
    proc.stdout.close()
    session = read_session(path)
    assert len(session.packets) > 200
    assert [p.t_ns for p in session.packets] == list(range(len(session.packets)))
    assert session.bad_records == 0


def test_unstorable_values_are_a_session_error(tmp_path: Path) -> None:
    with pytest.raises(SessionError, match="cannot store a header record"):
        SessionWriter(tmp_path / "a.scot", SessionHeader(source="simulated", scene={"x": object()}))
    with SessionWriter(tmp_path / "b.scot", HEADER) as writer, pytest.raises(SessionError):
        writer.write_packet(2**70, b"")
    assert read_session(tmp_path / "b.scot").packets == []


def test_source_frames_are_kept_and_skipped_unless_asked(tmp_path: Path) -> None:
    path = tmp_path / "imported.scotti"
    provenance = {"pressure": {"file": "p.csv", "rows": 3, "cols": 2}}
    header = SessionHeader(source="imported", imported=provenance)
    source = SourceFrameRecord(5, np.arange(12, dtype=np.float32).reshape(2, 3, 2))
    with SessionWriter(path, header) as writer:
        writer.write(source)
        writer.write_packet(10, b"\x01\x02")
    session = read_session(path)
    assert session.header.imported == provenance
    assert len(session.packets) == 1
    assert session.labels == []
    assert session.unknown_records == 0  # a kind this reader knows, skipped on purpose
    with SessionReader(path, source_frames=True) as reader:
        records = list(reader.records())
    assert isinstance(records[0], SourceFrameRecord)
    np.testing.assert_array_equal(records[0].frames, source.frames)
    assert records[0].t_ns == 5
    kinds = [type(r).__name__ for r in iter_records(path, source_frames=True)]
    assert kinds == ["SessionHeader", "SourceFrameRecord", "PacketRecord"]


AnyRecord = PacketRecord | LabelRecord | SourceFrameRecord | EventRecord


def mixed_records(count: int) -> list[AnyRecord]:
    """Every kind of record a writer stores; packets from empty to past the file's buffer."""
    rng = np.random.default_rng(7)
    records: list[AnyRecord] = []
    for i in range(count):
        if i % 50 == 0:
            source = rng.random((2, 3, 2), dtype=np.float32)
            records.append(SourceFrameRecord(1000 * i, source))
        if i % 7 == 0:
            records.append(EventRecord(1000 * i + 1, "step", f"at {i}", wall_ns=17 * i))
        if i % 3 == 0:
            records.append(label(i, action=-1 if i % 2 else 0))
        records.append(PacketRecord(1000 * i + 2, rng.bytes(int(rng.integers(0, 20_000)))))
    return records


@pytest.mark.parametrize("flush_each", [True, False])
def test_write_many_writes_the_bytes_of_one_write_per_record(
    tmp_path: Path, flush_each: bool
) -> None:
    records = mixed_records(300)
    one_by_one, bulk = tmp_path / "one.scot", tmp_path / "bulk.scot"
    with SessionWriter(one_by_one, HEADER, flush_each=flush_each) as writer:
        for record in records:
            writer.write(record)
    with SessionWriter(bulk, HEADER, flush_each=flush_each) as many:
        many.write_many(records[:1])
        many.write_many([])
        many.write_many(records[1:120])
        many.write_many(iter(records[120:]))  # any iterable, a generator too
    assert many.records == writer.records == 1 + len(records)  # the header is one
    assert bulk.read_bytes() == one_by_one.read_bytes()
    with SessionReader(bulk, source_frames=True, events=True) as reader:
        kinds = [type(r) for r in reader.records()]
    assert kinds == [type(r) for r in records]
    session = read_session(bulk)
    assert session.packets == [r for r in records if isinstance(r, PacketRecord)]
    assert session.labels == [r for r in records if isinstance(r, LabelRecord)]


def test_write_many_writes_none_of_a_batch_it_cannot_store(tmp_path: Path) -> None:
    path = tmp_path / "s.scot"
    with SessionWriter(path, HEADER) as writer:
        writer.write_many([PacketRecord(1, b"kept")])
        before = path.read_bytes()
        batch = [PacketRecord(2, b"a"), PacketRecord(2**70, b"b"), PacketRecord(3, b"c")]
        with pytest.raises(SessionError, match="cannot store a packet record"):
            writer.write_many(batch)
        assert path.read_bytes() == before
        assert writer.records == 2
    assert read_session(path).packets == [PacketRecord(1, b"kept")]
    with pytest.raises(SessionError, match="closed"):
        writer.write_many([PacketRecord(4, b"late")])
