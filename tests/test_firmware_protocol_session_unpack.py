"""Session records unpacked in bounded memory: shape limits, msgpack bombs, files cut
short or lying about their records' lengths, read through the real reader and CLI."""

from __future__ import annotations

import os
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

import msgpack
import numpy as np
import pytest
from scotti.cli.main import main as scotti_main
from scotti.firmware_protocol.errors import SessionError
from scotti.firmware_protocol.session import (
    MAGIC,
    EventRecord,
    LabelRecord,
    PacketRecord,
    SessionHeader,
    SessionWriter,
    SourceFrameRecord,
    read_session,
)
from scotti.firmware_protocol.session_unpack import (
    LIMITS,
    MAX_RECORD_LEN,
    SMALL_BODY,
    OverLimitError,
    ShapeLimits,
    UndecodableError,
    check_shape,
    unpack_checked,
    unpack_record,
)

REPO = Path(__file__).parents[1]
HEADER = SessionHeader(source="recorded", created_unix=0.0)
MiB = 1 << 20


def frame(body: bytes) -> bytes:
    """A record as the file holds it: u32 little-endian length, then the body."""
    return len(body).to_bytes(4, "little") + body


def packed(record: dict[str, object]) -> bytes:
    return msgpack.packb(record, use_bin_type=True)


def session_then(tmp_path: Path, *bodies: bytes, name: str = "s.ses") -> tuple[Path, list[int]]:
    """A file: magic, header, two packet records, then ``bodies`` as records; the path
    and the offset of each of ``bodies``' records."""
    head = MAGIC + frame(packed(HEADER.to_record()))
    head += frame(packed(PacketRecord(1, b"\x00ab").to_record()))
    head += frame(packed(PacketRecord(2, b"\x00cd").to_record()))
    offsets, data = [], bytearray(head)
    for body in bodies:
        offsets.append(len(data))
        data += frame(body)
    path = tmp_path / name
    path.write_bytes(data)
    return path, offsets


# --- what the writers write ------------------------------------------------------------


def _written_records() -> list[dict[str, object]]:
    rng = np.random.default_rng(0)
    return [
        HEADER.to_record(),
        SessionHeader(
            source="simulated", scene={"name": "s", "effects": [{"noise": 0.1}] * 20}
        ).to_record(),
        PacketRecord(123, rng.bytes(4096)).to_record(),
        LabelRecord(7, 8, rng.random((19, 3)), 2, 0.5, 1).to_record(),
        SourceFrameRecord(9, rng.random((2, 64, 32))).to_record(),  # 16 KiB: the fast gate
        SourceFrameRecord(9, rng.random((2, 128, 128))).to_record(),  # 128 KiB: checked
        EventRecord(10, "squat", "é" * 3000, 11).to_record(),
    ]


@pytest.mark.parametrize("record", _written_records(), ids=lambda r: str(r["kind"]))
def test_what_writers_write_unpacks_as_msgpack_unpacks_it(record: dict[str, object]) -> None:
    body = packed(record)
    expected = msgpack.unpackb(body, raw=False)
    assert unpack_record(body) == expected
    assert unpack_checked(body) == expected


def test_the_project_headers_fit_a_quarter_of_every_limit(tmp_path: Path) -> None:
    """The limits leave room: the simulator's richest header (a scene with effects)
    and an importer's provenance pass the shape check at a quarter of each limit."""
    simulated, imported = tmp_path / "demo.ses", tmp_path / "imported.ses"
    assert scotti_main(["sim", str(REPO / "sim/scenes/demo.toml"), "-o", str(simulated)]) == 0
    vendor = REPO / "tests/data/vendors/GaCo01_01_first5s.txt"
    assert scotti_main(["import", str(vendor), "-o", str(imported)]) == 0
    quarter = ShapeLimits(
        depth=LIMITS.depth // 4,
        values=LIMITS.values // 4,
        container_len=LIMITS.container_len // 4,
        str_len=LIMITS.str_len // 4,
    )
    for path in (simulated, imported):
        data = path.read_bytes()
        length = int.from_bytes(data[8:12], "little")
        header = data[12 : 12 + length]
        check_shape(header, quarter)
        assert msgpack.unpackb(header)["scene" if path is simulated else "imported"]


# --- shapes refused ----------------------------------------------------------------------

_K = b"\x81\xa1k"  # a map of one entry, key "k": what follows is its value


@pytest.mark.parametrize(
    ("body", "at", "words"),
    [
        (_K + b"\x91" * 40 + b"\x90", 3 + 31, "nested deeper than 32"),
        (_K + b"\xdd" + (1 << 20).to_bytes(4, "big") + b"\x90" * (1 << 20), 3, "array of 1048576"),
        (_K + b"\xdf" + (1 << 17).to_bytes(4, "big") + b"\xc0" * (1 << 18), 3, "map of 131072"),
        (  # many tiny containers, each short: 2 x 65535 empty arrays
            _K + b"\x92" + (b"\xdc\xff\xff" + b"\x90" * 65535) * 2,
            4 + 3 + 65535 + 3 + (LIMITS.values - 2 - 2 - 65535 - 1),
            "more than 131072 values",
        ),
        (_K + b"\xdb" + (2 * MiB).to_bytes(4, "big") + b"x" * (2 * MiB), 3, "string of 2097152"),
    ],
    ids=["deep", "wide-array", "wide-map", "many-tiny", "long-string"],
)
def test_bombs_are_over_the_limits_where_they_go_over(body: bytes, at: int, words: str) -> None:
    with pytest.raises(OverLimitError, match=words) as caught:
        unpack_record(body)
    assert caught.value.at == at


@pytest.mark.parametrize(
    "body",
    [
        b"\x93\x01\x02\x03",  # an array, not a map
        _K + b"\xdb\xff\xff\xff\xff" + b"x" * 10,  # a string longer than the record
        _K + b"\xc6\xff\xff\xff\xf0" + b"x" * 10,  # bytes longer than the record
        _K + b"\xdd\x00\x01\x00\x00" + b"\x90" * 10,  # more items than bytes left
        _K + b"\xc7\x01\x05x",  # an ext type: never written
        _K + b"\xc1",  # never a msgpack byte
        _K + b"\xcb\x00\x00",  # a float cut short
        _K + b"\x90\x90",  # a byte after the map
        b"\x81\x01\x02",  # a key that is not text
    ],
    ids=["array", "str", "bin", "items", "ext", "c1", "cut", "trailing", "int-key"],
)
def test_records_that_are_not_whole_maps_are_undecodable(body: bytes) -> None:
    with pytest.raises(UndecodableError):
        unpack_record(body)


def test_an_undecodable_record_is_skipped_and_an_over_limit_one_stops_the_read(
    tmp_path: Path,
) -> None:
    cut, _ = session_then(tmp_path, _K + b"\xdb\xff\xff\xff\xff", name="cut.ses")
    session = read_session(cut)
    assert (len(session.packets), session.bad_records) == (2, 1)
    bomb = _K + b"\x91" * 40 + b"\x90"
    path, (offset,) = session_then(tmp_path, bomb)
    with pytest.raises(SessionError) as caught:
        read_session(path)
    message = str(caught.value)
    assert "\n" not in message
    assert message.startswith(f"{path} is corrupt at byte {offset + 4 + 3 + 31}: ")
    assert f"in the record at {offset}" in message


def test_a_header_nested_too_deep_is_never_written(tmp_path: Path) -> None:
    scene: dict[str, object] = {}
    inner = scene
    for _ in range(LIMITS.depth):
        inner["x"] = {}
        inner = inner["x"]  # type: ignore[assignment]
    with pytest.raises(SessionError, match="nested deeper than 32"):
        SessionWriter(tmp_path / "deep.ses", SessionHeader(source="simulated", scene=scene))


def test_a_record_over_the_largest_is_never_written(tmp_path: Path) -> None:
    with (
        SessionWriter(tmp_path / "big.ses", HEADER) as writer,
        pytest.raises(SessionError, match=f"at most {MAX_RECORD_LEN}"),
    ):
        writer.write_packet(1, bytes(MAX_RECORD_LEN))
    assert read_session(tmp_path / "big.ses").packets == []


# --- files cut short, lengths that lie ---------------------------------------------------


def test_a_file_cut_inside_a_large_record_reads_its_whole_records(tmp_path: Path) -> None:
    path = tmp_path / "cut.ses"
    with SessionWriter(path, HEADER) as writer:
        writer.write_packet(1, b"first")
        writer.write(SourceFrameRecord(2, np.ones((2, 256, 256))))  # 512 KiB
        writer.write_packet(3, b"never read")
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    tracemalloc.start()
    try:
        session = read_session(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert session.packets == [PacketRecord(1, b"first")]
    assert session.truncated
    assert peak < 64 << 10  # the cut record's 512 KiB were never asked for


def test_a_record_claiming_more_than_the_file_holds_allocates_nothing(tmp_path: Path) -> None:
    path, _ = session_then(tmp_path)
    with path.open("ab") as f:  # claims the largest record; ten bytes follow
        f.write(MAX_RECORD_LEN.to_bytes(4, "little") + b"\x83" + b"x" * 9)
    tracemalloc.start()
    try:
        session = read_session(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert [r.t_ns for r in session.packets] == [1, 2]
    assert session.truncated
    assert peak < MiB  # not the 16 MiB it claims


def test_a_length_past_the_largest_record_is_corrupt_where_it_stands(tmp_path: Path) -> None:
    path, (offset,) = session_then(tmp_path, b"")
    data = bytearray(path.read_bytes())
    data[offset : offset + 4] = (MAX_RECORD_LEN + 1).to_bytes(4, "little")
    path.write_bytes(bytes(data) + bytes(100))
    with pytest.raises(SessionError, match=f"record of {MAX_RECORD_LEN + 1} bytes at offset"):
        read_session(path)


# --- a bomb under a memory cap, through the command line ----------------------------------

# Run in a child: address space capped at what it holds after its imports plus
# 256 MiB (the 16 MiB file read whole fits; unpacking the bomb took 1.2 GB).
_CAPPED = """
import resource, sys
import numpy
from scotti.cli.main import main
from scotti.firmware_protocol import cli, session_summary
with open("/proc/self/statm") as f:
    held = int(f.read().split()[0]) * resource.getpagesize()
cap = held + (256 << 20)
resource.setrlimit(resource.RLIMIT_AS, (cap, cap))
sys.exit(main(["session", "info", sys.argv[1]]))
"""


def _bomb(kind: str) -> bytes:
    n = MAX_RECORD_LEN - 16
    if kind == "wide":  # 16 MiB of empty arrays in one array
        return _K + b"\xdd" + n.to_bytes(4, "big") + b"\x90" * n
    if kind == "many":  # 255 arrays of 65535 empty arrays: none over the length limit
        return _K + b"\xdc\x00\xff" + (b"\xdc\xff\xff" + b"\x90" * 65535) * 255
    return _K + b"\x91" * (n - 1) + b"\x90"  # 16 MiB of nested arrays


@pytest.mark.skipif(not Path("/proc/self/statm").exists(), reason="needs Linux /proc")
@pytest.mark.parametrize("kind", ["wide", "many", "deep"])
def test_a_bomb_file_fails_in_one_line_under_a_memory_cap(tmp_path: Path, kind: str) -> None:
    path, (offset,) = session_then(tmp_path, _bomb(kind), name=f"{kind}.ses")
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    started = time.monotonic()
    done = subprocess.run(
        [sys.executable, "-c", _CAPPED, str(path)],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
        check=False,
    )
    seconds = time.monotonic() - started
    assert done.returncode == 2, done.stderr[-2000:]
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr[-2000:]
    assert lines[0].startswith(f"scotti session: {path} is corrupt at byte ")
    assert f"in the record at {offset}" in lines[0]
    assert seconds < 60  # it took 15 s and 1.2 GB unbounded; the check stops early


def test_small_records_take_the_fast_gate_and_large_ones_the_check() -> None:
    """Both ways give the same map; the gate's bound is what keeps small bodies cheap."""
    small = packed({"kind": "packet", "t_ns": 1, "data": bytes(SMALL_BODY - 100)})
    large = packed({"kind": "packet", "t_ns": 1, "data": bytes(SMALL_BODY + 100)})
    assert unpack_record(small)["data"] == bytes(SMALL_BODY - 100)
    assert unpack_record(large)["data"] == bytes(SMALL_BODY + 100)
    nested = b"\xde\x00\x02\xa1a\x01\xa1b\xdc\x00\x20" + b"\x01" * 32  # map16: checked
    assert unpack_record(nested) == {"a": 1, "b": [1] * 32}
