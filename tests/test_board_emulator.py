"""The board emulator, read back through pyserial on a real pseudo-terminal."""

from __future__ import annotations

import itertools
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import serial
from scotti.daemon.input.board_emulator import BoardEmulator, EmulatorError
from scotti.daemon.input.speed import Speed, parse_speed
from scotti.firmware_protocol.framing import StreamDecoder
from scotti.firmware_protocol.packets import Foot, FrameRows

from tests.support.sessions import SyntheticSession, synthetic_counts, write_synthetic_session

Factory = Callable[..., BoardEmulator]
SCOTTI = (sys.executable, "-m", "scotti.cli.main")


def read_exactly(port: serial.Serial, n: int, timeout: float = 10.0) -> bytes:
    out = bytearray()
    deadline = time.monotonic() + timeout
    while len(out) < n and time.monotonic() < deadline:
        out += port.read(n - len(out))
    return bytes(out)


def wait_for(condition: Callable[[], bool], timeout: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.02)
    return condition()


def test_reader_gets_exactly_the_session_bytes(
    board_factory: Factory, synthetic_session: SyntheticSession
) -> None:
    board = board_factory(synthetic_session.path, speed="max")
    with serial.Serial(str(board.link), timeout=0.2) as port:
        data = read_exactly(port, len(synthetic_session.data))
        assert port.read(100) == b""  # nothing more than the session
    assert data == synthetic_session.data
    packets = StreamDecoder().feed(data)
    assert all(isinstance(p, FrameRows) for p in packets)
    rows = [p for p in packets if isinstance(p, FrameRows)]
    assert len(rows) == synthetic_session.frames * 2 * 4
    first_left = np.vstack([p.samples for p in rows[:4]])
    assert rows[0].foot == Foot.LEFT
    assert np.array_equal(first_left, synthetic_counts(Foot.LEFT, 0))
    assert [p.seq for p in rows if p.foot == Foot.RIGHT][::4] == synthetic_session.seqs[Foot.RIGHT]
    assert board.finished.wait(2.0)
    assert board.stats.records_written == len(synthetic_session.records)
    assert board.stats.records_dropped == 0


def test_unplug_removes_link_and_fails_reads_replug_brings_a_new_port(
    board_factory: Factory, synthetic_session: SyntheticSession
) -> None:
    board = board_factory(synthetic_session, speed=1.0, loop=True)
    port = serial.Serial(str(board.link), timeout=0.5)
    try:
        assert port.read(64)  # bytes flow
        board.unplug()
        assert not board.link.exists()
        assert not board.link.is_symlink()
        assert not board.plugged
        with pytest.raises(serial.SerialException):
            read_exactly(port, 1 << 20, timeout=2.0)  # a closed pty fails the read
    finally:
        port.close()
    board.replug()
    assert board.link.is_symlink()
    assert os.readlink(board.link) == board.device
    with serial.Serial(str(board.link), timeout=0.5) as again:
        data = read_exactly(again, 2000, timeout=3.0)
    assert len(data) == 2000
    assert board.stats.unplugs == 1
    assert board.stats.replugs == 1


def test_speed_one_keeps_the_recorded_pace_and_max_does_not(tmp_path: Path) -> None:
    session = write_synthetic_session(tmp_path / "s.scotti", frames=12)
    elapsed: dict[Speed, float] = {}
    speeds: tuple[Speed, ...] = (1.0, "max")
    for speed in speeds:
        link = tmp_path / f"tty{speed}"
        with BoardEmulator(session.records, link, speed=speed):
            start = time.monotonic()
            with serial.Serial(str(link), timeout=0.2) as port:
                data = read_exactly(port, len(session.data))
            elapsed[speed] = time.monotonic() - start
        assert data == session.data
    duration_s = session.duration_ns / 1e9  # ~0.7 s
    assert elapsed[1.0] >= 0.9 * duration_s
    assert elapsed["max"] < duration_s / 3


def test_a_reader_that_does_not_read_costs_dropped_records_not_a_hang(
    board_factory: Factory, synthetic_session: SyntheticSession
) -> None:
    board = board_factory(synthetic_session, speed="max", write_timeout_s=0.05)
    with serial.Serial(str(board.link)):  # opened, never read
        assert wait_for(lambda: board.stats.records_dropped > 0)
        assert board.unread_bytes() > 1000  # the pty buffer is full, nobody took it
        start = time.monotonic()
        board.stop()
    assert time.monotonic() - start < 1.0
    assert not board.link.is_symlink()


def test_plays_only_while_a_reader_has_the_port_open(
    board_factory: Factory, synthetic_session: SyntheticSession
) -> None:
    board = board_factory(synthetic_session, speed="max")
    time.sleep(0.3)
    assert board.stats.bytes_written == 0
    with serial.Serial(str(board.link), timeout=0.5) as port:
        assert read_exactly(port, 100) == synthetic_session.data[:100]
        board.pause()
        time.sleep(0.2)
        port.reset_input_buffer()
        written = board.stats.bytes_written
        assert port.read(10) == b""  # paused: a stall on an open port
        board.resume()
        port.timeout = 5.0  # a loaded machine may take a while to schedule the board again
        assert port.read(10)
    # The reader can hold the bytes before the board's thread has counted them.
    assert wait_for(lambda: board.stats.bytes_written > written)


def test_refuses_to_replace_a_real_file(tmp_path: Path) -> None:
    target = tmp_path / "not-a-link"
    target.write_text("keep me")
    with pytest.raises(EmulatorError, match="not a symlink"):
        BoardEmulator([(0, b"x")], target).start()
    assert target.read_text() == "keep me"


def test_parse_speed() -> None:
    assert parse_speed("max") == "max"
    assert parse_speed("2.5") == 2.5
    for bad in ("0", "-1", "fast", "inf"):
        with pytest.raises(ValueError, match=r"."):
            parse_speed(bad)


def test_one_parse_speed_for_text_and_numbers_with_one_message() -> None:
    assert parse_speed(" MAX ") == "max"
    assert parse_speed(8) == 8.0
    assert parse_speed(0.5) == 0.5
    for bad in ("nan", 0, -2.0, float("inf"), None, "x"):
        with pytest.raises(ValueError, match=r"^speed must be a positive number or 'max', got "):
            parse_speed(bad)


def test_cli_unplugs_replugs_on_signals_and_exits_cleanly_on_sigterm(
    tmp_path: Path, synthetic_session: SyntheticSession
) -> None:
    link = tmp_path / "ttyCLI"
    cmd = [*SCOTTI, "board", str(synthetic_session.path)]
    proc = subprocess.Popen(
        [*cmd, "--link", str(link), "--loop"],
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert wait_for(link.is_symlink, timeout=15.0), "the board never made its link"
        with serial.Serial(str(link), timeout=1.0) as port:
            assert port.read(16)
        proc.send_signal(signal.SIGUSR1)
        assert wait_for(lambda: not link.is_symlink())
        proc.send_signal(signal.SIGUSR2)
        assert wait_for(link.is_symlink)
        proc.send_signal(signal.SIGTERM)
        _, stderr = proc.communicate(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, stderr
    assert not link.is_symlink()
    assert "unplugged" in stderr
    assert "replugged" in stderr


def test_cli_reports_a_missing_session_in_one_line(tmp_path: Path) -> None:
    result = subprocess.run(
        [*SCOTTI, "board", str(tmp_path / "nope.scotti"), "--link", str(tmp_path / "tty")],
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
    )
    assert result.returncode == 2
    assert len(result.stderr.strip().splitlines()) == 1
    assert "nope.scotti" in result.stderr


@pytest.mark.parametrize("continue_numbers", [True, False])
def test_a_loop_goes_on_with_the_boards_numbers_or_starts_them_over(
    board_factory: Factory, tmp_path: Path, continue_numbers: bool
) -> None:
    frames = 80  # 5 s: a jump back over all of it is a restart to the assembler (>= 64)
    session = write_synthetic_session(
        tmp_path / "loop.scotti", frames=frames, seq_start=65_500, garbage_every=7, labels=False
    )
    board = board_factory(session, speed="max", loop=True, continue_numbers=continue_numbers)
    with serial.Serial(str(board.link), timeout=0.2) as port:
        data = read_exactly(port, 2 * len(session.data) + len(session.data) // 2)
    assert wait_for(lambda: board.stats.loops_completed >= 2)
    items = StreamDecoder().feed(data)
    blocks = [p for p in items if isinstance(p, FrameRows) and p.foot == Foot.LEFT]
    seqs = [b.seq for b in blocks if b.row_start == 0]  # one per frame
    clocks = [b.board_clock_us for b in blocks if b.row_start == 0]
    assert len(seqs) > 2 * frames
    steps = {(b - a) % 65536 for a, b in itertools.pairwise(seqs)}
    ticks = {(b - a) % (1 << 32) for a, b in itertools.pairwise(clocks)}
    if continue_numbers:
        assert steps == {1}  # through the wrap at 65535 and across both loop boundaries
        assert ticks == {62_500}  # the board clock too, one frame at 16 Hz
        assert seqs[frames] == (65_500 + frames) % 65536
    else:
        assert steps == {1, (1 - frames) % 65536}  # back to the first frame at each loop
    # The line noise between packets is sent as it is: it still fails to decode, in
    # every loop (two whole ones read at least).
    errors = [e for e in items if not isinstance(e, FrameRows)]
    assert len(errors) >= 2 * (frames // 7)
