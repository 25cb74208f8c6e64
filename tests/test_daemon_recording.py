"""Recording: the byte stream before decoding, into a session file that survives kill -9."""

from __future__ import annotations

import asyncio
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from scotti.daemon.counters import Counters
from scotti.daemon.pipeline import Pipeline
from scotti.daemon.recording import Recorder, RecordingError
from scotti.daemon.sources import ReplaySource
from scotti.firmware_protocol.session import read_session
from scotti.models.runtime import ScottiRuntime

from tests.support.sessions import write_synthetic_session


def test_recorded_chunks_read_back_as_packet_records(tmp_path: Path) -> None:
    path = tmp_path / "rec.scotti"
    with Recorder(path, device="bench") as recorder:
        for i in range(20):
            recorder.tap(1_000 + i, bytes([i]) * (i + 1))
    session = read_session(path)
    assert session.header.source == "recorded"
    assert session.header.device == "bench"
    assert [(p.t_ns, p.data) for p in session.packets] == [
        (1_000 + i, bytes([i]) * (i + 1)) for i in range(20)
    ]
    assert not session.truncated
    assert recorder.records == 20


def test_an_existing_file_is_never_overwritten(tmp_path: Path) -> None:
    path = tmp_path / "walk.scotti"
    path.write_bytes(b"precious")
    with Recorder(path) as recorder:
        recorder.tap(1, b"x")
    assert path.read_bytes() == b"precious"
    assert recorder.path == tmp_path / "walk.1.scotti"
    assert read_session(recorder.path).packets[0].data == b"x"


def test_a_recording_that_cannot_start_is_one_line(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match="cannot create session file") as info:
        Recorder(tmp_path / "no" / "such" / "dir.scotti")
    assert "\n" not in str(info.value)


CHILD = textwrap.dedent(
    """
    import sys
    from scotti.daemon.recording import Recorder
    recorder = Recorder(sys.argv[1])
    i = 0
    while True:
        recorder.tap(i, i.to_bytes(4, "little") * 256)
        if i % 50 == 0:
            print(i, flush=True)
        i += 1
    """
)


def test_a_recording_killed_mid_write_reads_back_to_its_last_whole_record(
    tmp_path: Path,
) -> None:
    path = tmp_path / "killed.scotti"
    child = subprocess.Popen(
        [sys.executable, "-c", CHILD, str(path)], stdout=subprocess.PIPE, text=True
    )
    assert child.stdout is not None
    reported = -1
    try:
        while reported < 300:
            reported = int(child.stdout.readline())
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait()
        child.stdout.close()
    assert child.returncode == -signal.SIGKILL
    session = read_session(path)  # no exception: a cut file still reads
    assert len(session.packets) > reported  # every record reported flushed is there
    for i, packet in enumerate(session.packets):
        assert packet.t_ns == i
        assert packet.data == i.to_bytes(4, "little") * 256


def test_the_pipeline_records_the_bytes_as_they_came(tmp_path: Path, tiny_model_path: Path) -> None:
    session = write_synthetic_session(tmp_path / "in.scotti", frames=12, garbage_every=3)
    recorder = Recorder(tmp_path / "out.scotti")
    pipeline = Pipeline(
        ReplaySource(session.path, speed="max"),
        ScottiRuntime(tiny_model_path),
        Counters(),
        recorder,
    )
    start = time.monotonic()
    asyncio.run(pipeline.run(lambda _: None, lambda _: None, asyncio.Event()))
    recorder.close()
    assert time.monotonic() - start < 10
    recorded = read_session(recorder.path)
    assert b"".join(p.data for p in recorded.packets) == session.data  # garbage included
