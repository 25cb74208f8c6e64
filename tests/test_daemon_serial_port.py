"""The receiver's port read without pyserial's select(): real bytes through a real pty,
a port whose descriptor is numbered past 1024 (where select() refuses), and a port
that goes away still reported as pyserial reports it."""

from __future__ import annotations

import asyncio
import contextlib
import os
import resource
import tty
from collections.abc import Callable, Iterator

import pytest
import serial
from scotti.daemon.input.board_emulator import BoardEmulator
from scotti.daemon.input.serial_port import LoopSerial, open_port

from tests.support.sessions import SyntheticSession

Factory = Callable[..., BoardEmulator]
PAST_SELECT = 1100  # select() takes descriptors below 1024 only


@contextlib.contextmanager
def descriptors_past_select() -> Iterator[None]:
    """Every descriptor below PAST_SELECT taken, so the next one opened is past it."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft != resource.RLIM_INFINITY and soft < PAST_SELECT + 64:
        if hard != resource.RLIM_INFINITY and hard < PAST_SELECT + 64:
            pytest.skip(f"the descriptor limit ({hard}) is below {PAST_SELECT + 64}")
        resource.setrlimit(resource.RLIMIT_NOFILE, (PAST_SELECT + 64, hard))
    taken: list[int] = []
    try:
        while not taken or taken[-1] < PAST_SELECT:
            taken.append(os.open(os.devnull, os.O_RDONLY))
        yield
    finally:
        for fd in taken:
            os.close(fd)
        resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))


async def _read_all(reader: asyncio.StreamReader, n: int) -> bytes:
    out = bytearray()
    async with asyncio.timeout(10):
        while len(out) < n:
            out += await reader.read(4096)
    return bytes(out)


def test_a_port_past_descriptor_1024_delivers_every_byte(
    board_factory: Factory, synthetic_session: SyntheticSession
) -> None:
    async def body() -> tuple[int, bytes]:
        reader, writer = await open_port(str(board.link), 115200)
        try:
            fd = writer.transport.get_extra_info("serial").fileno()
            return fd, await _read_all(reader, len(synthetic_session.data))
        finally:
            writer.close()
            await asyncio.sleep(0.05)  # the transport closes the port on the loop's next turn

    with descriptors_past_select():  # the emulated board's pty past 1024 too
        board = board_factory(synthetic_session, speed="max")
        fd, data = asyncio.run(body())
    assert fd >= PAST_SELECT  # pyserial's own read would raise ValueError from select() here
    assert data == synthetic_session.data


@pytest.fixture
def pty_port() -> Iterator[tuple[int, str]]:
    leader, follower = os.openpty()
    tty.setraw(follower)
    name = os.ttyname(follower)
    os.close(follower)
    yield leader, name
    with contextlib.suppress(OSError):
        os.close(leader)


def test_a_read_with_nothing_waiting_is_empty_and_bytes_come_as_written(
    pty_port: tuple[int, str],
) -> None:
    leader, name = pty_port
    with LoopSerial(name, timeout=0) as port:
        assert port.read(4096) == b""
        os.write(leader, b"\x01\x02\x00")
        for _ in range(100):  # a pty hands bytes over within a tick
            got = port.read(4096)
            if got:
                break
            asyncio.run(asyncio.sleep(0.01))
        assert got == b"\x01\x02\x00"


def test_a_port_that_went_away_raises_as_pyserial_does(pty_port: tuple[int, str]) -> None:
    leader, name = pty_port
    with LoopSerial(name, timeout=0) as port:
        os.close(leader)  # the receiver unplugged: its tty hangs up
        with pytest.raises(serial.SerialException, match=r"read failed|returned no data"):
            port.read(4096)


def test_a_closed_port_is_not_read() -> None:
    port = LoopSerial()
    with pytest.raises(serial.PortNotOpenError):
        port.read(1)
