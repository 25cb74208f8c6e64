"""Where the bytes come from: the receiver's serial port, or a session file replayed.

Every source is an async stream of ``(host_mono_ns, bytes)`` chunks and
``SourceEvent`` values (connected / disconnected, with a reason). The
pipeline does not care which source it reads: replay and the simulated
board (``sources_sim``) run exactly the live path.

The serial source survives anything the port does: absent at start,
unplugged, stalled (no byte for ``stall_s``), busy or forbidden. It reports
each change once and tries again with a capped, jittered exponential backoff.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import logging
import threading
import time
from collections.abc import AsyncGenerator, AsyncIterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Final, Literal, Protocol, TypeAlias

import serial
from scotti.daemon.errors import DaemonError
from scotti.daemon.input.serial_port import open_port
from scotti.daemon.input.speed import Speed
from scotti.daemon.waiting import Backoff

if TYPE_CHECKING:
    from scotti.firmware_protocol.session import PacketRecord

log = logging.getLogger(__name__)

READ_SIZE: Final = 4096  # bytes asked for per read; a 16 Hz pair of frames is ~3 KB
_YIELD_EVERY: Final = 64  # replay at max speed gives the loop a turn every this many records
# Replay reads its file a batch at a time, one batch ahead: this many bytes of packet
# data or records, whichever comes first (about 20 s of a pair at 16 Hz; a record
# costs ~100 bytes of Python besides its data).
READ_AHEAD_BYTES: Final = 1 << 20
READ_AHEAD_RECORDS: Final = 4096


class SourceError(DaemonError):
    """A source that cannot start at all (a replay file that is not a session)."""


@dataclass(frozen=True)
class SourceEvent:
    kind: Literal["connected", "disconnected"]
    reason: str = ""


Chunk: TypeAlias = tuple[int, bytes]  # (host monotonic ns when read, bytes as received)
SourceItem: TypeAlias = Chunk | SourceEvent


class Source(Protocol):
    """What the pipeline reads. ``live`` False: it may be slowed down (backpressure)."""

    name: str
    live: bool

    def stream(self) -> AsyncGenerator[SourceItem, None]: ...


class PortUnavailableError(DaemonError):
    """The port cannot be opened now; ``str()`` is the reason for ``status``."""


def explain_open_error(port: str, exc: BaseException) -> str:
    """One line saying why ``port`` did not open and, where there is one, the fix."""
    code = getattr(exc, "errno", None)
    if code in (errno.ENOENT, errno.ENODEV, errno.ENXIO):
        return f"{port} not found (receiver unplugged?)"
    if code in (errno.EACCES, errno.EPERM):
        return (
            f"permission denied on {port}: add the user to the 'dialout' group "
            "(sudo usermod -aG dialout $USER, then log in again)"
        )
    if code in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EBUSY):
        return f"{port} is in use by another process (it holds the exclusive lock)"
    return f"cannot open {port}: {exc}"


class SerialSource:
    """The receiver board on a serial port, reopened whenever it goes away."""

    live = True

    def __init__(
        self,
        port: str,
        *,
        baudrate: int = 921_600,  # ignored by USB CDC receivers, needed by UART bridges
        stall_s: float = 0.5,
        backoff: Backoff | None = None,
        played: threading.Event | None = None,
    ) -> None:
        self.port = port
        self.name = f"serial {port}"
        self.baudrate = baudrate
        self.stall_s = stall_s
        self.backoff = backoff if backoff is not None else Backoff()
        # Set by a board that has sent everything it will (the simulated board played
        # once): the stream then ends at the first stall, which is the end, not a fault.
        self.played = played

    def __aiter__(self) -> AsyncIterator[SourceItem]:
        return self.stream()

    async def stream(self) -> AsyncGenerator[SourceItem, None]:
        reported: str | None = None  # the last disconnect reason already yielded
        while True:
            try:
                reader, writer = await self._open()
            except PortUnavailableError as exc:
                reason = str(exc)
                if reason != reported:
                    # One WARNING per outage: the cut itself, or the first failed open at
                    # start; a new reason while still away (lost -> not found) is INFO.
                    level = logging.WARNING if reported is None else logging.INFO
                    log.log(level, "receiver: %s", reason)
                    yield SourceEvent("disconnected", reason)
                    reported = reason
                await asyncio.sleep(self.backoff.next_delay())
                continue
            log.info("receiver: %s opened", self.port)
            watch = _StallWatch(reader, self.stall_s)
            try:
                yield SourceEvent("connected", f"{self.port} opened")
                ended: str | None = None
                while ended is None:
                    chunk, ended = await self._read(reader, watch)
                    if chunk is None and self.played is not None and self.played.is_set():
                        log.info("receiver: %s: the board has played everything", self.port)
                        yield SourceEvent("disconnected", "end of scene")
                        return
                    if chunk is not None:
                        reported = None  # bytes flowed: the next failure is a new outage
                        if self.backoff.attempt:
                            self.backoff.reset()  # bytes flowed: the next outage starts afresh
                        yield chunk
            finally:
                watch.stop()
                await _close(writer)
            # A port that opens but stays silent (insoles off) is one WARNING, not one
            # per reopen: after the first, the same outage goes on at INFO.
            log.log(logging.WARNING if reported is None else logging.INFO, "receiver: %s", ended)
            yield SourceEvent("disconnected", ended)
            reported = ended
            await asyncio.sleep(self.backoff.next_delay())

    async def _open(self) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
        try:
            reader, writer = await open_port(self.port, self.baudrate)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise PortUnavailableError(explain_open_error(self.port, exc)) from None
        return reader, writer

    async def _read(
        self, reader: asyncio.StreamReader, watch: _StallWatch
    ) -> tuple[Chunk | None, str | None]:
        """One chunk, or the reason the connection is over."""
        watch.reading_since = watch.loop.time()
        try:
            data = await reader.read(READ_SIZE)
        except _StalledError:
            return None, f"no bytes from {self.port} for {self.stall_s:g} s (stalled)"
        except (serial.SerialException, OSError) as exc:
            return None, f"{self.port} lost: {exc}"
        finally:
            watch.reading_since = None
        if not data:
            return None, f"{self.port} closed"
        return (time.monotonic_ns(), data), None


class _StalledError(DaemonError):
    """No byte came for ``stall_s``: the waiting read ends with this."""


class _StallWatch:
    """Ends a read that has waited ``stall_s`` for a byte, with one timer that looks
    every ``stall_s`` or so instead of a timeout armed and disarmed around every read
    (about 4 us a read, several reads per frame pair). The read ends through the
    reader's ``set_exception``, never by cancelling the task that reads: a stall never
    lands anywhere but in the read (the connection is closed after it)."""

    def __init__(self, reader: asyncio.StreamReader, stall_s: float) -> None:
        self.loop = asyncio.get_running_loop()
        self.reading_since: float | None = None  # loop time a read began waiting, if one is
        self._reader = reader
        self._stall_s = stall_s
        self._handle = self.loop.call_later(stall_s, self._look)

    def _look(self) -> None:
        since, now = self.reading_since, self.loop.time()
        if since is not None and now - since >= self._stall_s:
            self._reader.set_exception(_StalledError())
            return
        due = self._stall_s if since is None else since + self._stall_s - now
        self._handle = self.loop.call_later(due, self._look)

    def stop(self) -> None:
        self._handle.cancel()


async def _close(writer: asyncio.StreamWriter) -> None:
    """Close without flushing (the port may be gone) and wait until it is closed."""
    # The library closes the transport itself when a read fails (unplug). Its abort() is
    # not idempotent: a second one schedules a second connection-lost task that fails on
    # the protocol already gone, and asyncio logs "Task exception was never retrieved".
    if not writer.transport.is_closing():
        writer.transport.abort()
    with contextlib.suppress(Exception):
        async with asyncio.timeout(2.0):
            await writer.wait_closed()


@dataclass(frozen=True)
class ReplayPlan:
    """What a pass over a session file to replay found."""

    packets: int  # whole packet records
    first_t_ns: int  # the first one's host time: the replay's time zero


def check_replay(path: Path) -> ReplayPlan:
    """One pass over a session file to replay, in bounded memory; ``SourceError``
    (one line) when it is not a session, has a record over the reader's limits
    (a corrupt file, a msgpack bomb) or holds nothing to replay.

    A file cut short inside its last record (a recorder killed, a disk full) is
    replayed up to its last whole record, with one WARNING saying so: its records
    are whole and what they hold is what was received. Records that cannot be
    read are skipped, also with one WARNING.
    """
    from scotti.firmware_protocol.errors import SessionError
    from scotti.firmware_protocol.session import PacketRecord, SessionReader

    packets, first_t_ns = 0, 0
    try:
        with SessionReader(path) as reader:
            for record in reader:
                if isinstance(record, PacketRecord):
                    if not packets:
                        first_t_ns = record.t_ns
                    packets += 1
    except SessionError as exc:
        raise SourceError(f"replay: {exc}") from None
    if not packets:
        cut = ", cut short" if reader.truncated else ""
        msg = f"replay: {path} holds no packet records{cut}: nothing to replay"
        raise SourceError(msg)
    if reader.truncated:
        log.warning(
            "replay: %s ends inside a record (cut short): replaying its %d whole packet records",
            path,
            packets,
        )
    if reader.bad_records:
        log.warning("replay: %s: %d records cannot be read, skipped", path, reader.bad_records)
    return ReplayPlan(packets, first_t_ns)


class _Batches:
    """A session file's packet records, a batch at a time, read in a thread of its
    own: the replay holds at most the batch it plays and the one read ahead."""

    def __init__(self, path: Path) -> None:
        from scotti.firmware_protocol.session import SessionReader

        self._reader = SessionReader(path)
        self._records = iter(self._reader)
        self._thread = ThreadPoolExecutor(1, thread_name_prefix="replay-read")
        self._ahead: Future[list[PacketRecord]] | None = None

    def _read(self) -> list[PacketRecord]:
        from scotti.firmware_protocol.session import PacketRecord

        batch: list[PacketRecord] = []
        size = 0
        for record in self._records:
            if isinstance(record, PacketRecord):
                batch.append(record)
                size += len(record.data)
                if size >= READ_AHEAD_BYTES or len(batch) >= READ_AHEAD_RECORDS:
                    break
        return batch

    async def next(self) -> list[PacketRecord]:
        """The next batch (empty at the end), with the one after it set reading."""
        if self._ahead is None:
            self._ahead = self._thread.submit(self._read)
        batch = await asyncio.wrap_future(self._ahead)
        self._ahead = self._thread.submit(self._read) if batch else None
        return batch

    def close(self) -> None:
        """Close the file once the thread is done with it (one thread: in order)."""
        self._thread.submit(self._reader.close)
        self._thread.shutdown(wait=False)


class ReplaySource:
    """A session file's packet records fed back at ``speed`` (1 = as recorded, or max).

    Not live: the pipeline may make it wait rather than drop frames, so a replay
    is deterministic (the same file gives the same predictions). The chunks carry
    the host time at which they are handed on, so latencies stay meaningful.
    The file is checked whole when the source is made (one that holds nothing to
    replay, or a corrupt record, stops the daemon at start: ``SourceError``, like
    any other bad setting) and then streamed: read a batch ahead, never held.
    """

    live = False

    def __init__(self, path: Path | str, *, speed: Speed = 1.0) -> None:
        self.path = Path(path)
        self.speed = speed
        self.name = f"replay {self.path.name}"
        self.plan = check_replay(self.path)

    def __aiter__(self) -> AsyncIterator[SourceItem]:
        return self.stream()

    async def stream(self) -> AsyncGenerator[SourceItem, None]:
        from scotti.firmware_protocol.errors import SessionError

        yield SourceEvent("connected", f"replaying {self.path.name}")
        base_ns = time.monotonic_ns()
        t0 = self.plan.first_t_ns
        i = 0
        try:
            batches = _Batches(self.path)
        except SessionError as exc:  # gone or changed since the check
            log.error("replay: %s", exc)
            yield SourceEvent("disconnected", f"replay: {exc}")
            return
        try:
            while batch := await batches.next():
                for record in batch:
                    if self.speed == "max":
                        if i % _YIELD_EVERY == 0:
                            await asyncio.sleep(0)
                    else:
                        due = base_ns + (record.t_ns - t0) / self.speed
                        delay = (due - time.monotonic_ns()) / 1e9
                        if delay > 0:
                            await asyncio.sleep(delay)
                    i += 1
                    yield time.monotonic_ns(), record.data
        except SessionError as exc:  # the file changed under the replay
            log.error("replay: %s", exc)
            yield SourceEvent("disconnected", f"replay: {exc}")
            return
        finally:
            batches.close()
        yield SourceEvent("disconnected", "end of replay")
