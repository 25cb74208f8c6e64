"""The serial port's descriptor read straight: every byte in order, a reader that falls
behind holds a bounded amount, stalls and a vanished port end the reads."""

from __future__ import annotations

import asyncio
import contextlib
import os
import threading
import tty
from collections.abc import Iterator

import pytest
import serial
from scotti.daemon.input.port_reader import GONE, HELD_MAX, READ_MAX, STALLED, PortReader


@pytest.fixture
def pty_pair() -> Iterator[tuple[int, str]]:
    """A pseudo-terminal: the board's end (a descriptor) and the port's device path."""
    leader, follower = os.openpty()
    tty.setraw(follower)
    path = os.ttyname(follower)
    yield leader, path
    for fd in (leader, follower):
        with contextlib.suppress(OSError):  # a test may have closed the board's end
            os.close(fd)


def open_port(path: str) -> serial.Serial:
    return serial.Serial(path, baudrate=921_600, exclusive=True)


def test_every_byte_arrives_in_order_and_a_late_reader_holds_a_bounded_amount(
    pty_pair: tuple[int, str],
) -> None:
    leader, path = pty_pair
    data = bytes(range(256)) * 2048  # 512 KiB, eight times what the reader may hold

    def write_all() -> None:
        view = memoryview(data)
        while view:
            view = view[os.write(leader, view) :]

    writer = threading.Thread(target=write_all)

    async def body() -> tuple[bytes, int]:
        reader = PortReader(open_port(path), stall_s=2.0)
        writer.start()
        await asyncio.sleep(0.3)  # behind: the port is read until HELD_MAX, then waits
        held = reader._held
        got = bytearray()
        times = []
        while len(got) < len(data):
            chunk = await reader.read()
            assert not isinstance(chunk, str), chunk
            times.append(chunk[0])
            got += chunk[1]
        reader.close()
        assert times == sorted(times)
        return bytes(got), held

    got, held = asyncio.run(asyncio.wait_for(body(), 20))
    writer.join(5)
    assert got == data
    assert HELD_MAX <= held <= HELD_MAX + READ_MAX  # it stopped reading, and lost nothing


def test_a_read_waiting_stall_s_without_a_byte_ends_stalled(pty_pair: tuple[int, str]) -> None:
    leader, path = pty_pair

    async def body() -> tuple[object, object, float]:
        reader = PortReader(open_port(path), stall_s=0.2)
        os.write(leader, b"abc")
        first = await reader.read()
        start = asyncio.get_running_loop().time()
        second = await reader.read()
        waited = asyncio.get_running_loop().time() - start
        reader.close()
        return first, second, waited

    first, second, waited = asyncio.run(asyncio.wait_for(body(), 10))
    assert isinstance(first, tuple)
    assert first[1] == b"abc"
    assert second == STALLED
    assert 0.18 <= waited < 1.5


def test_a_port_whose_other_end_closes_ends_the_reads(pty_pair: tuple[int, str]) -> None:
    leader, path = pty_pair

    async def body() -> object:
        reader = PortReader(open_port(path), stall_s=5.0)
        os.write(leader, b"last words")
        assert (await reader.read()) != STALLED
        os.close(leader)  # the receiver unplugged
        end = await reader.read()
        reader.close()
        return end

    end = asyncio.run(asyncio.wait_for(body(), 10))
    assert end == GONE or (isinstance(end, str) and end.startswith("read failed: "))


def test_closing_releases_the_port_for_the_next_open(pty_pair: tuple[int, str]) -> None:
    _, path = pty_pair

    async def body() -> None:
        reader = PortReader(open_port(path), stall_s=5.0)
        with pytest.raises(serial.SerialException):
            open_port(path)  # locked: one reader at a time
        reader.close()
        open_port(path).close()

    asyncio.run(asyncio.wait_for(body(), 10))
