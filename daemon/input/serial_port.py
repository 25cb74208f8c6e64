"""The receiver's port on the event loop: pyserial's port, read without its ``select()``.

pyserial-asyncio-fast puts the port's descriptor in the event loop's selector
(epoll on Linux) and, once it is readable, calls ``Serial.read``. pyserial's
POSIX ``read`` then waits for the same descriptor again with ``select()``
before its ``os.read``: a second system call per read for nothing, and
``select()`` refuses any descriptor numbered 1024 or more. A daemon holds about
six descriptors a pair (docs/performance.md), so by that count a process
serving some 165 pairs, or a port reopened while a browser view holds many
sockets, would get a port whose every read fails (bench_floor's 210 ports in
one process did). ``LoopSerial.read`` is the one ``os.read``; what
pyserial's read says of a port that went away, it says the same way.

Ports given as pyserial URLs (``socket://``, ``rfc2217://``, ``loop://``) open
as pyserial opens them.
"""

from __future__ import annotations

import asyncio
import errno
import os
import termios
from functools import partial

import serial
import serial_asyncio_fast

# What a non-blocking read of an empty port (or an interrupted one) raises: nothing to read.
_NOTHING_YET = (errno.EAGAIN, errno.EWOULDBLOCK, errno.EINTR)


class LoopSerial(serial.Serial):
    """A POSIX serial port whose ``read`` is one non-blocking ``os.read``: what is waiting,
    ``b""`` when nothing is; a port that went away raises ``SerialException``."""

    def _reconfigure_port(self, force_update: bool = False) -> None:
        super()._reconfigure_port(force_update)  # type: ignore[misc]
        # pyserial leaves VMIN at 0 (its timeouts are select()'s), and then a read of an
        # empty port returns b"" as a hung-up one does. With VMIN 1 and O_NONBLOCK (pyserial
        # opens the port so) an empty port says EAGAIN, and b"" means only: gone.
        fd = getattr(self, "fd", None)
        if fd is None:
            return
        attrs = termios.tcgetattr(fd)
        attrs[6][termios.VMIN], attrs[6][termios.VTIME] = 1, 0
        termios.tcsetattr(fd, termios.TCSANOW, attrs)

    def read(self, size: int = 1) -> bytes:
        fd = getattr(self, "fd", None)  # set by open()
        if not self.is_open or fd is None:
            raise serial.PortNotOpenError()
        try:
            data = os.read(fd, size)
        except OSError as exc:
            if exc.errno in _NOTHING_YET:
                return b""
            msg = f"read failed: {exc}"
            raise serial.SerialException(msg) from None
        if not data:  # end of file: the device is gone
            msg = (
                "device reports readiness to read but returned no data "
                "(device disconnected or multiple access on port?)"
            )
            raise serial.SerialException(msg)
        return data


async def open_port(port: str, baudrate: int) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
    """``serial_asyncio_fast.open_serial_connection`` for ``port``, exclusive, with a
    ``LoopSerial`` where the port is a device path."""
    if "://" in port or os.name != "posix":
        return await serial_asyncio_fast.open_serial_connection(
            url=port, baudrate=baudrate, exclusive=True
        )
    loop = asyncio.get_running_loop()
    # Opening a port can block (a USB device settling): off the loop, as pyserial-asyncio does.
    instance = await loop.run_in_executor(
        None, partial(LoopSerial, port, baudrate=baudrate, exclusive=True)
    )
    reader = asyncio.StreamReader(loop=loop)
    protocol = asyncio.StreamReaderProtocol(reader, loop=loop)
    try:
        transport, _ = await serial_asyncio_fast.connection_for_serial(
            loop, lambda: protocol, instance
        )
    except BaseException:
        instance.close()
        raise
    return reader, asyncio.StreamWriter(transport, protocol, reader, loop)
