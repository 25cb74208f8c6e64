"""Sources: the serial source through a real pty with the board emulator, and replay."""

from __future__ import annotations

import asyncio
import contextlib
import errno
import itertools
import logging
import time
from collections.abc import Awaitable, Callable
from pathlib import Path

import pytest
import serial
from scotti.daemon.input.board_emulator import BoardEmulator
from scotti.daemon.input.simulated import SimulatedSource
from scotti.daemon.input.sources import (
    ReplaySource,
    SerialSource,
    Source,
    SourceError,
    SourceEvent,
    SourceItem,
    explain_open_error,
)
from scotti.daemon.waiting import Backoff
from scotti.firmware_protocol.framing import StreamDecoder
from scotti.firmware_protocol.packets import FrameRows

from tests.support.sessions import SyntheticSession, write_synthetic_session

Factory = Callable[..., BoardEmulator]


class Tap:
    """Runs a source in a task and queues what it yields, so a test can wait with timeouts."""

    def __init__(self, source: Source) -> None:
        self.items: asyncio.Queue[SourceItem] = asyncio.Queue()
        self._task = asyncio.create_task(self._pump(source))

    async def _pump(self, source: Source) -> None:
        async for item in source.stream():
            await self.items.put(item)

    async def next_event(self, within: float = 5.0) -> tuple[SourceEvent, int]:
        """The next event, and how many data bytes came before it."""
        nbytes = 0
        async with asyncio.timeout(within):
            while True:
                item = await self.items.get()
                if isinstance(item, SourceEvent):
                    return item, nbytes
                nbytes += len(item[1])

    async def read_bytes(self, n: int, within: float = 10.0) -> bytes:
        out = bytearray()
        async with asyncio.timeout(within):
            while len(out) < n:
                item = await self.items.get()
                assert not isinstance(item, SourceEvent), item
                out += item[1]
        return bytes(out)

    async def close(self) -> None:
        self._task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await self._task


def run(body: Callable[[], Awaitable[None]]) -> None:
    asyncio.run(asyncio.wait_for(body(), 30))


def fast_backoff() -> Backoff:
    return Backoff(initial_s=0.02, cap_s=0.2)


def test_serial_source_delivers_the_board_bytes(
    board_factory: Factory, synthetic_session: SyntheticSession
) -> None:
    board = board_factory(synthetic_session, speed="max")

    async def body() -> None:
        tap = Tap(SerialSource(str(board.link)))
        event, _ = await tap.next_event()
        assert event.kind == "connected"
        data = await tap.read_bytes(len(synthetic_session.data))
        await tap.close()
        assert data == synthetic_session.data

    run(body)


def test_unplug_disconnects_and_replug_reconnects_within_the_backoff(
    board_factory: Factory, synthetic_session: SyntheticSession
) -> None:
    board = board_factory(synthetic_session, speed=4.0, loop=True)

    async def body() -> None:
        tap = Tap(SerialSource(str(board.link), backoff=fast_backoff()))
        assert (await tap.next_event())[0].kind == "connected"
        await tap.read_bytes(1000)
        await asyncio.to_thread(board.unplug)
        event, _ = await tap.next_event(within=2.0)
        assert event.kind == "disconnected"
        event, _ = await tap.next_event(within=2.0)  # retries find no port
        assert event == SourceEvent("disconnected", f"{board.link} not found (receiver unplugged?)")
        start = time.monotonic()
        await asyncio.to_thread(board.replug)
        event, _ = await tap.next_event(within=2.0)
        assert event.kind == "connected"
        assert time.monotonic() - start < 1.0  # the 0.2 s cap, plus slack for a loaded machine
        assert await tap.read_bytes(1000)
        await tap.close()

    run(body)


def test_a_stall_counts_as_a_disconnect_and_the_source_reconnects(
    board_factory: Factory, synthetic_session: SyntheticSession
) -> None:
    board = board_factory(synthetic_session, speed=4.0, loop=True)

    async def body() -> None:
        tap = Tap(SerialSource(str(board.link), stall_s=0.3, backoff=fast_backoff()))
        assert (await tap.next_event())[0].kind == "connected"
        await tap.read_bytes(500)
        await asyncio.to_thread(board.pause)
        start = time.monotonic()
        event, _ = await tap.next_event(within=3.0)
        assert event.kind == "disconnected"
        assert "stalled" in event.reason
        assert time.monotonic() - start >= 0.25
        await asyncio.to_thread(board.resume)
        # It reopens the port (connected), possibly stalls again before the resume lands.
        while (event := (await tap.next_event(within=3.0))[0]).kind != "connected":
            pass
        assert await tap.read_bytes(500)
        await tap.close()

    run(body)


def test_a_port_that_keeps_sending_is_never_stalled_even_by_a_slow_reader(
    board_factory: Factory, synthetic_session: SyntheticSession
) -> None:
    board = board_factory(synthetic_session, speed=4.0, loop=True)

    async def body() -> None:
        stream = SerialSource(str(board.link), stall_s=0.2, backoff=fast_backoff()).stream()
        kinds: list[str] = []
        nbytes = 0
        start = time.monotonic()
        async for item in stream:
            if isinstance(item, SourceEvent):
                kinds.append(item.kind)
            else:
                if not nbytes:
                    await asyncio.sleep(0.5)  # busy with the first chunk for 2.5 stall_s
                nbytes += len(item[1])
            if time.monotonic() - start > 1.5:
                break
        await stream.aclose()
        assert kinds == ["connected"]
        assert nbytes > 1000

    run(body)


def test_a_port_absent_at_start_is_waited_for(
    tmp_path: Path, synthetic_session: SyntheticSession
) -> None:
    link = tmp_path / "ttyLATE"

    async def body() -> None:
        tap = Tap(SerialSource(str(link), backoff=fast_backoff()))
        event, _ = await tap.next_event()
        assert event.kind == "disconnected"
        assert "not found" in event.reason
        with BoardEmulator(synthetic_session.records, link, speed="max"):
            event, _ = await tap.next_event(within=3.0)
            assert event.kind == "connected"
            data = await tap.read_bytes(len(synthetic_session.data))
            assert data == synthetic_session.data
            await tap.close()

    run(body)


def test_the_port_is_locked_for_one_reader(
    board_factory: Factory, synthetic_session: SyntheticSession
) -> None:
    board = board_factory(synthetic_session, speed=1.0, loop=True)

    async def body() -> None:
        first = Tap(SerialSource(str(board.link)))
        assert (await first.next_event())[0].kind == "connected"
        second = Tap(SerialSource(str(board.link), backoff=fast_backoff()))
        event, _ = await second.next_event()
        assert event.kind == "disconnected"
        assert "in use" in event.reason
        await second.close()
        await first.close()

    run(body)


def test_garbage_on_the_line_is_counted_and_every_packet_still_arrives(
    board_factory: Factory, tmp_path: Path
) -> None:
    session = write_synthetic_session(tmp_path / "g.scotti", frames=16, garbage_every=2)
    board = board_factory(session, speed="max")
    decoder = StreamDecoder()

    async def body() -> None:
        tap = Tap(SerialSource(str(board.link)))
        assert (await tap.next_event())[0].kind == "connected"
        data = await tap.read_bytes(len(session.data))
        await tap.close()
        items = decoder.feed(data)
        assert sum(isinstance(i, FrameRows) for i in items) == 16 * 2 * 4
        assert decoder.counters.errors >= 8  # one bad run per garbage record at least

    run(body)


def test_permission_denied_names_the_group_to_join() -> None:
    exc = serial.SerialException(errno.EACCES, "could not open port /dev/ttyACM0: denied")
    reason = explain_open_error("/dev/ttyACM0", exc)
    assert "add the user to the 'dialout' group" in reason
    assert reason.count("\n") == 0


def test_backoff_grows_is_capped_and_jittered() -> None:
    backoff = Backoff(initial_s=0.1, cap_s=1.0, jitter=0.5)
    delays = [backoff.next_delay() for _ in range(8)]
    assert 0.05 <= delays[0] <= 0.1
    assert all(0.5 <= d <= 1.0 for d in delays[5:])
    assert len(set(delays)) == len(delays)  # jitter: no two the same
    backoff.reset()
    assert backoff.next_delay() <= 0.1


@pytest.mark.parametrize("speed", [1.0, "max"])
def test_replay_yields_the_recorded_bytes_at_the_recorded_pace(
    tmp_path: Path, speed: float | str
) -> None:
    session = write_synthetic_session(tmp_path / "r.scotti", frames=8)

    async def body() -> None:
        items = []
        start = time.monotonic()
        async for item in ReplaySource(session.path, speed=speed).stream():  # type: ignore[arg-type]
            items.append(item)
        elapsed = time.monotonic() - start
        assert items[0] == SourceEvent("connected", "replaying r.scotti")
        assert items[-1] == SourceEvent("disconnected", "end of replay")
        chunks = [i for i in items[1:-1] if not isinstance(i, SourceEvent)]
        assert [data for _, data in chunks] == [data for _, data in session.records]
        assert all(b[0] >= a[0] for a, b in itertools.pairwise(chunks))
        if speed == 1.0:
            assert elapsed >= 0.9 * session.duration_ns / 1e9
        else:
            assert elapsed < session.duration_ns / 1e9 / 3

    run(body)


SHORT_SCENE = """
description = "a short squat for tests"
seed = 3
rate = 16.0

[subject]
height_m = 1.75
mass_kg = 72.0
style_seed = 11

[[script]]
action = "squat"
duration_s = 4.0
stand_s = 0.5
"""


def test_simulated_source_plays_a_scene_through_a_pty(tmp_path: Path) -> None:
    scene = tmp_path / "short.toml"
    scene.write_text(SHORT_SCENE)
    source = SimulatedSource(scene, speed="max")

    async def body() -> None:
        tap = Tap(source)
        event, _ = await tap.next_event(within=20.0)
        assert event == SourceEvent("disconnected", "rendering scene short")
        event, _ = await tap.next_event(within=20.0)
        assert event.kind == "connected"
        assert source.emulator is not None
        link = source.emulator.link
        assert link.is_symlink()
        data = await tap.read_bytes(20_000)
        await tap.close()
        assert not link.is_symlink()  # the emulator stopped with the stream
        packets = [p for p in StreamDecoder().feed(data) if isinstance(p, FrameRows)]
        assert len(packets) > 20

    run(body)


def test_an_unknown_or_broken_scene_is_refused_when_the_source_is_made(tmp_path: Path) -> None:
    with pytest.raises(SourceError, match="no shipped scene"):
        SimulatedSource("no-such-scene")
    broken = tmp_path / "broken.toml"
    broken.write_text('[subject]\nheight_m = 1.7\nmass_kg = 70\n[[script]]\naction = "dance"\n')
    with pytest.raises(SourceError, match=r"broken\.toml line 5: script\[0\]\.action"):
        SimulatedSource(broken)


def test_unplug_and_replug_log_no_error(
    board_factory: Factory, synthetic_session: SyntheticSession, caplog: pytest.LogCaptureFixture
) -> None:
    """The serial library's close path must leave no task exception unretrieved."""
    import gc

    board = board_factory(synthetic_session, speed=8.0, loop=True)
    caplog.set_level(logging.DEBUG)

    async def body() -> None:
        tap = Tap(SerialSource(str(board.link), backoff=fast_backoff()))
        assert (await tap.next_event())[0].kind == "connected"
        for _ in range(3):
            await tap.read_bytes(500)
            await asyncio.to_thread(board.unplug)
            assert (await tap.next_event(within=2.0))[0].kind == "disconnected"
            await asyncio.to_thread(board.replug)
            while (await tap.next_event(within=3.0))[0].kind != "connected":
                pass
        await tap.read_bytes(500)
        await tap.close()
        await asyncio.sleep(0.1)  # the library's close tasks finish
        gc.collect()  # an unretrieved task exception is logged when the task is collected

    run(body)
    gc.collect()
    errors = [r for r in caplog.records if r.levelno >= logging.ERROR]
    assert errors == [], [r.getMessage() for r in errors]
    assert any("opened" in r.getMessage() for r in caplog.records)  # the logs were captured


# --- replay streams its file ----------------------------------------------------------

# Run in a child: drain a replay at max speed and say how far the process's peak RSS
# rose above what it held before the source was made (MiB). VmHWM, not ru_maxrss:
# that one starts a child at its parent's size when it forks.
_DRAIN = """
import asyncio, hashlib, sys
from scotti.daemon.input.sources import ReplaySource

def status_kib(field):
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith(field + ":"))

async def drain(path):
    chunks, digest = 0, hashlib.sha256()
    async for item in ReplaySource(path, speed="max").stream():
        if isinstance(item, tuple):
            chunks += 1
            digest.update(item[1])
    return chunks, digest.hexdigest()

held = status_kib("VmRSS")
chunks, digest = asyncio.run(drain(sys.argv[1]))
print(chunks, digest, (status_kib("VmHWM") - held) // 1024)
"""


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs Linux /proc")
def test_replay_holds_a_batch_of_its_file_not_the_file(tmp_path: Path) -> None:
    """128 MiB of packets replayed: the process's peak grows by less than half of that
    (held whole, by 147 MiB; streamed, by about 16: the read-ahead and what the
    allocator keeps after the check's pass)."""
    import hashlib
    import subprocess
    import sys

    from scotti.firmware_protocol.session import PacketRecord, SessionHeader, SessionWriter

    path, records, size = tmp_path / "big.scotti", 32_768, 4096
    digest = hashlib.sha256()
    with SessionWriter(path, SessionHeader(source="recorded"), flush_each=False) as writer:
        for start in range(0, records, 1024):
            batch = [
                PacketRecord(i * 1_000_000, i.to_bytes(4, "little") * (size // 4))
                for i in range(start, start + 1024)
            ]
            writer.write_many(batch)
            for record in batch:
                digest.update(record.data)
    done = subprocess.run(
        [sys.executable, "-c", _DRAIN, str(path)],
        capture_output=True,
        text=True,
        timeout=300,
        check=True,
    )
    chunks, got, rise_mib = done.stdout.split()
    assert (int(chunks), got) == (records, digest.hexdigest())  # every byte, in order
    assert int(rise_mib) < 64, f"peak RSS rose {rise_mib} MiB replaying a 128 MiB file"


def test_a_replay_stopped_early_closes_its_file_and_thread(tmp_path: Path) -> None:
    import threading

    session = write_synthetic_session(tmp_path / "r.scotti", frames=400)

    async def body() -> None:
        source = ReplaySource(session.path, speed="max")
        async with contextlib.aclosing(source.stream()) as items:
            async for item in items:
                if not isinstance(item, SourceEvent):
                    break

    run(body)
    deadline = time.monotonic() + 10
    while any(t.name.startswith("replay-read") for t in threading.enumerate()):
        assert time.monotonic() < deadline, "the replay's reading thread is still alive"
        time.sleep(0.01)


def test_a_replay_with_a_bomb_after_its_packets_is_refused_at_start(tmp_path: Path) -> None:
    """The whole file is checked before anything plays: a msgpack bomb at its end
    is one line, with the byte, when the source is made."""
    session = write_synthetic_session(tmp_path / "r.scotti", frames=4)
    offset = session.path.stat().st_size
    bomb = b"\x81\xa1k" + b"\x91" * 100_000 + b"\x90"  # nested arrays, past the 64 KiB gate
    with session.path.open("ab") as f:
        f.write(len(bomb).to_bytes(4, "little") + bomb)
    with pytest.raises(SourceError) as caught:
        ReplaySource(session.path)
    message = str(caught.value)
    assert message.startswith(f"replay: {session.path} is corrupt at byte {offset + 4 + 3 + 31}")
    assert "nested deeper than 32" in message
    assert "\n" not in message
