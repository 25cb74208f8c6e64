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
from scotti.daemon.frames.pipeline import Pipeline
from scotti.daemon.input.recording import Recorder, RecordingError, candidate_paths, recording_path
from scotti.daemon.input.sources import ReplaySource
from scotti.daemon.service.counters import Counters
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


def test_a_fixed_name_that_exists_is_refused_with_the_hint(tmp_path: Path) -> None:
    path = tmp_path / "walk.scotti"
    path.write_bytes(b"precious")
    with pytest.raises(RecordingError) as info:
        Recorder(path)
    assert str(info.value) == (
        f"{path} exists and is never overwritten; for a new file at every start put {{time}} "
        f"in the name ({tmp_path / 'walk-{time}.scotti'}) or give a directory, else move the "
        "file away"
    )
    assert path.read_bytes() == b"precious"
    assert [p.name for p in tmp_path.iterdir()] == ["walk.scotti"]


def test_time_and_device_in_the_name_make_a_new_file_at_every_start(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, "scotti.daemon.input.recording")
    template = tmp_path / "{device}-walk-{time}.scotti"
    before = datetime.now(UTC).replace(microsecond=0)
    recorders = [Recorder(template, device="lab1") for _ in range(3)]  # a restart loop
    after = datetime.now(UTC)
    for r in recorders:
        r.close()
    paths = [r.path for r in recorders]
    assert len(set(paths)) == 3  # within one second too: a made name takes .1, .2
    for path in paths:
        match = re.fullmatch(r"lab1-walk-(\d{8}T\d{6})(\.\d)?\.scotti", path.name)
        assert match is not None, path.name
        stamp = datetime.strptime(match[1], "%Y%m%dT%H%M%S").replace(tzinfo=UTC)
        assert before <= stamp <= after  # the UTC start time
        assert read_session(path).header.device == "lab1"
    logged = [r.getMessage() for r in caplog.records]
    assert [f"recording to {p}" for p in paths] == logged


def test_a_made_name_that_is_taken_gets_a_counter(tmp_path: Path) -> None:
    at = datetime(2026, 11, 21, 13, 56, 30, tzinfo=UTC)
    path, made = recording_path(tmp_path / "walk-{time}.scotti", "lab1", at, ".scotti")
    assert (path.name, made) == ("walk-20261121T135630.scotti", True)
    names = [p.name for p in itertools.islice(candidate_paths(path), 3)]
    assert names == [
        "walk-20261121T135630.scotti",
        "walk-20261121T135630.1.scotti",
        "walk-20261121T135630.2.scotti",
    ]
    fixed, made = recording_path(tmp_path / "walk.scotti", "lab1", at, ".scotti")
    assert (fixed.name, made) == ("walk.scotti", False)


def test_an_unknown_placeholder_is_one_line(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match=r"unknown placeholder \{tme\} \(known: "):
        Recorder(tmp_path / "walk-{tme}.scotti")
    assert list(tmp_path.iterdir()) == []


def test_a_recording_that_cannot_start_is_one_line(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match="cannot create session file") as info:
        Recorder(tmp_path / "no" / "such" / "dir.scotti")
    assert "\n" not in str(info.value)


CHILD = textwrap.dedent(
    """
    import sys
    from scotti.daemon.input.recording import Recorder
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
def test_the_daemon_records_into_a_new_file_per_start_and_names_it_in_info(
    mosquitto: Mosquitto, tiny_model_path: Path, tmp_path: Path
) -> None:
    session = write_synthetic_session(tmp_path / "in.scotti", frames=44)
    template = tmp_path / "rec-{time}.scotti"
    with collect(mosquitto, "scotti/rec/#") as got:
        args = ["--replay", str(session.path), "--speed", "max", "--model", str(tiny_model_path)]
        args += ["--broker", mosquitto.url, "--device-id", "rec", "--record", str(template)]
        daemon = start_daemon(args, tmp_path / "rec.log")
        assert daemon.wait(60) == 0, daemon.log
        got.wait_for(lambda m: bool(payloads(m, "info")), 5, "info")
    info = payloads(got.snapshot(), "info")[0]
    actual = Path(info["settings"]["record"])
    assert re.fullmatch(r"rec-\d{8}T\d{6}\.scotti", actual.name), actual.name
    assert actual.parent == tmp_path
    assert info["settings"]["record_requested"] == str(template)
    names = ("status", "info", "pose", "action", "progress", "health", "pressure")
    assert info["topics"] == {n: f"scotti/rec/{n}" for n in names}
    recorded = read_session(actual)
    assert b"".join(p.data for p in recorded.packets) == session.data
    assert f"INFO scotti.daemon.input.recording: recording to {actual}" in daemon.log


def test_the_daemon_will_not_start_over_a_fixed_recording_name_that_exists(
    tiny_model_path: Path, tmp_path: Path
) -> None:
    # What a restart loop meets with a fixed name: exit 78 and the hint, the file kept.
    session = write_synthetic_session(tmp_path / "in.scotti", frames=4)
    existing = tmp_path / "rec.scotti"
    existing.write_bytes(b"yesterday")
    args = ["--replay", str(session.path), "--model", str(tiny_model_path)]
    args += ["--broker", "mqtt://127.0.0.1:1", "--record", str(existing)]
    daemon = start_daemon(args, tmp_path / "d.log")
    assert daemon.wait(60) == 78, daemon.log
    last = daemon.log.strip().splitlines()[-1]
    assert last.startswith(f"scotti-daemon: error: {existing} exists and is never overwritten;")
    assert "put {time} in the name" in last
    assert existing.read_bytes() == b"yesterday"


def test_record_into_a_directory_makes_a_named_file_inside_it(tmp_path: Path) -> None:
    folder = tmp_path / "recordings"
    folder.mkdir()
    with Recorder(folder, device="lab1") as recorder:
        recorder.tap(1, b"\x00")
    assert recorder.path.parent == folder  # inside, not a sibling next to it
    assert re.fullmatch(r"lab1-\d{8}T\d{6}\.scotti", recorder.path.name), recorder.path.name
    assert sorted(p.name for p in tmp_path.iterdir()) == ["recordings"]
    assert read_session(recorder.path).header.device == "lab1"
