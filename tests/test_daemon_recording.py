"""Recording: the byte stream before decoding, into a session file that survives kill -9."""

from __future__ import annotations

import asyncio
import itertools
import logging
import re
import signal
import subprocess
import sys
import textwrap
import time
from datetime import UTC, datetime
from pathlib import Path

import pytest
from scotti.daemon.counters import Counters
from scotti.daemon.pipeline import Pipeline
from scotti.daemon.recording import Recorder, RecordingError, candidate_paths
from scotti.daemon.sources import ReplaySource
from scotti.daemon.tools.local_broker import Mosquitto
from scotti.firmware_protocol.session import read_session
from scotti.models.runtime import ScottiRuntime

from tests.support.broker import collect, payloads, start_daemon
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


def test_an_existing_file_is_never_overwritten(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, "scotti.daemon.recording")
    path = tmp_path / "walk.scotti"
    path.write_bytes(b"precious")
    before = datetime.now(UTC).replace(microsecond=0)
    with Recorder(path) as recorder:
        recorder.tap(1, b"x")
    after = datetime.now(UTC)
    assert path.read_bytes() == b"precious"
    match = re.fullmatch(r"walk\.(\d{8}T\d{6})\.scotti", recorder.path.name)
    assert match is not None, recorder.path
    assert recorder.path.parent == tmp_path
    stamp = datetime.strptime(match[1], "%Y%m%dT%H%M%S").replace(tzinfo=UTC)
    assert before <= stamp <= after  # the UTC start time
    assert read_session(recorder.path).packets[0].data == b"x"
    assert [r.levelno for r in caplog.records if str(recorder.path) in r.getMessage()] == [
        logging.INFO
    ]


def test_a_taken_stamped_name_gets_a_counter(tmp_path: Path) -> None:
    path = tmp_path / "walk.scotti"
    at = datetime(2026, 11, 21, 13, 56, 30, tzinfo=UTC)
    names = [p.name for p in itertools.islice(candidate_paths(path, at), 4)]
    assert names == [
        "walk.scotti",
        "walk.20261121T135630.scotti",
        "walk.20261121T135630.1.scotti",
        "walk.20261121T135630.2.scotti",
    ]
    path.write_bytes(b"first")
    recorders = [Recorder(path) for _ in range(3)]  # within one second: same stamp, mostly
    for r in recorders:
        r.close()
    paths = [r.path for r in recorders]
    assert len(set(paths)) == 3
    assert path not in paths
    assert path.read_bytes() == b"first"
    assert all(read_session(p).header.source == "recorded" for p in paths)


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


@pytest.mark.mosquitto
@pytest.mark.slow
def test_the_daemon_records_beside_an_existing_file_and_names_it_in_info(
    mosquitto: Mosquitto, tiny_model_path: Path, tmp_path: Path
) -> None:
    session = write_synthetic_session(tmp_path / "in.scotti", frames=44)
    existing = tmp_path / "rec.scotti"
    existing.write_bytes(b"an earlier recording")
    with collect(mosquitto, "scotti/rec/#") as got:
        args = ["--replay", str(session.path), "--speed", "max", "--model", str(tiny_model_path)]
        args += ["--broker", mosquitto.url, "--device-id", "rec", "--record", str(existing)]
        daemon = start_daemon(args, tmp_path / "rec.log")
        assert daemon.wait(60) == 0, daemon.log
        got.wait_for(lambda m: bool(payloads(m, "info")), 5, "info")
    assert existing.read_bytes() == b"an earlier recording"
    info = payloads(got.snapshot(), "info")[0]
    actual = Path(info["settings"]["record"])
    assert actual != existing
    assert actual.parent == tmp_path
    assert info["settings"]["record_requested"] == str(existing)
    names = ("status", "info", "pose", "action", "progress", "health", "pressure")
    assert info["topics"] == {n: f"scotti/rec/{n}" for n in names}
    recorded = read_session(actual)
    assert b"".join(p.data for p in recorded.packets) == session.data
    assert f"INFO scotti.daemon.recording: recording to {actual}" in daemon.log


def test_record_into_a_directory_makes_a_named_file_inside_it(tmp_path: Path) -> None:
    folder = tmp_path / "recordings"
    folder.mkdir()
    with Recorder(folder, device="lab1") as recorder:
        recorder.tap(1, b"\x00")
    assert recorder.path.parent == folder  # inside, not a sibling next to it
    assert re.fullmatch(r"lab1-\d{8}T\d{6}\.scotti", recorder.path.name), recorder.path.name
    assert sorted(p.name for p in tmp_path.iterdir()) == ["recordings"]
    assert read_session(recorder.path).header.device == "lab1"
