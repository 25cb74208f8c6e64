"""A fake receiver board: a session file's bytes played into a pseudo-terminal.

The emulator opens a pty, points a symlink (``--link``) at its follower
device and writes the recorded packet bytes into the leader at the recorded
pace (``t_ns`` deltas / speed; ``"max"`` = as fast as the reader takes them).
Anything that opens the link, pyserial included, sees a serial port.

One thread owns the file descriptors. ``unplug``/``replug``/``stop`` are
requests that thread executes between two writes, so a caller in a test, in
another thread or in an event loop (``await asyncio.to_thread(emu.unplug)``)
never races a write on a closed (or reused) descriptor; each call returns once
the change is done, within a few tens of milliseconds.

Behaviour worth knowing:
- Like a USB receiver that streams only once the host has opened the port,
  the board plays while a reader has the pty open and pauses (and resumes
  paced from that moment) while none has; playback starts ``settle_s`` after
  a reader appears, because pyserial flushes the input buffer on open.
- Unplug closes the pty (the reader's next read fails) and removes the link;
  replug opens a new pty behind the same link. Playback pauses while unplugged
  and resumes with the next record.
- A reader that does not read fills the pty buffer. A record that cannot be
  written within ``write_timeout_s`` is dropped (the rest of it) and counted,
  as a USB receiver drops what the host does not take; the board never blocks.
- ``line`` (settable at any time, from any thread) is what the line does to
  each record before it is written: return the bytes (changed or not), or
  None to lose the record (counted in ``records_lost``). The fault soak uses
  it to silence one foot.
- ``loop=True`` starts over at the end, and the board's numbers go on: from the
  second time round each packet's frame sequence number, board clock and
  uptime move on by one loop (``board_loops``), so the host sees one long
  session, and a recording of it reads as one (no restart at the loop).
  ``continue_numbers=False`` sends the records as they are instead: the
  numbers jump back once per loop, as after a board reset.
"""

from __future__ import annotations

import contextlib
import fcntl
import logging
import os
import queue
import select
import termios
import threading
import time
import tty
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Final, Literal

from scotti.daemon.errors import DaemonError
from scotti.daemon.input.board_loops import LoopRewriter, loop_steps
from scotti.daemon.input.speed import Speed

log = logging.getLogger(__name__)

_POLL_S: Final = 0.02  # longest the thread waits before looking at requests again
_DEFAULT_GAP_NS: Final = 62_500_000  # pause between two loops when a session has one record


class EmulatorError(DaemonError):
    """The emulator cannot start: bad link path, unreadable session."""


@dataclass
class EmulatorStats:
    """What the board did; read it from any thread (ints, updated by the writer)."""

    records_written: int = 0
    bytes_written: int = 0
    records_dropped: int = 0  # records (partly) dropped: the reader did not take them in time
    records_lost: int = 0  # records ``line`` took away
    bytes_dropped: int = 0
    loops_completed: int = 0
    unplugs: int = 0
    replugs: int = 0


@dataclass
class _Request:
    op: Literal["unplug", "replug", "pause", "resume", "stop", "inq"]
    done: threading.Event = field(default_factory=threading.Event)
    result: int = 0


class BoardEmulator:
    """Plays ``records`` ((t_ns, bytes) pairs) into a pty reachable at ``link``."""

    def __init__(
        self,
        records: Sequence[tuple[int, bytes]],
        link: Path | str,
        *,
        speed: Speed = 1.0,
        loop: bool = False,
        write_timeout_s: float = 0.5,
        settle_s: float = 0.1,
        continue_numbers: bool = True,
    ) -> None:
        self.records = list(records)
        self.link = Path(link)
        self.speed = speed
        self.loop = loop
        self.write_timeout_s = write_timeout_s
        self.settle_s = settle_s
        self.stats = EmulatorStats()
        self.line: Callable[[bytes], bytes | None] | None = None  # see the module docstring
        self.finished = threading.Event()  # set when a non-looping playback has ended
        self._requests: queue.SimpleQueue[_Request] = queue.SimpleQueue()
        self._wake = threading.Event()
        self._thread: threading.Thread | None = None
        self._leader: int | None = None
        self._device: str | None = None
        self._stopping = False
        self._paused = False
        self._reader_since: float | None = None  # monotonic time a reader opened the pty
        # Playback position: index of the next record, schedule base, bytes left of the current.
        self._index = 0
        self._base_ns: int | None = None
        self._pending = memoryview(b"")
        self._deadline = 0.0
        # Looping: the numbers' steps, worked out now (a whole pass of decoding: at the
        # loop's end it would stall the stream).
        looped = loop and continue_numbers and self.records
        steps = loop_steps(self.records, self._loop_ns()) if looped else None
        self._rewriter = LoopRewriter(steps) if steps is not None else None

    def _loop_ns(self) -> int:
        """One loop's host time at speed 1: the records' span and one mean interval."""
        t0, t_last = self.records[0][0], self.records[-1][0]
        gap = (t_last - t0) // (len(self.records) - 1) if len(self.records) > 1 else 0
        return t_last - t0 + (gap or _DEFAULT_GAP_NS)

    @classmethod
    def from_session(
        cls,
        path: Path | str,
        link: Path | str,
        *,
        speed: Speed = 1.0,
        loop: bool = False,
        continue_numbers: bool = True,
    ) -> BoardEmulator:
        """An emulator for the packet records of a session file."""
        from scotti.firmware_protocol.errors import SessionError
        from scotti.firmware_protocol.session import read_session

        try:
            session = read_session(Path(path))
        except SessionError as exc:
            raise EmulatorError(str(exc)) from None
        records = [(p.t_ns, bytes(p.data)) for p in session.packets]
        if not records:
            msg = f"{path}: no packet records to play"
            raise EmulatorError(msg)
        return cls(records, link, speed=speed, loop=loop, continue_numbers=continue_numbers)

    # --- public controls (thread-safe) -------------------------------------

    @property
    def device(self) -> str | None:
        """The pty follower device the link points at; None while unplugged."""
        return self._device

    @property
    def plugged(self) -> bool:
        return self._device is not None

    def start(self) -> None:
        """Open the pty, create the link and start playing."""
        if self._thread is not None:
            return
        self._check_link_free()
        self._open_pty()
        self._thread = threading.Thread(target=self._run, name="board-emulator", daemon=True)
        self._thread.start()

    def unplug(self) -> None:
        """Close the pty and remove the link, as pulling the USB cable would."""
        self._call("unplug")

    def replug(self) -> None:
        """A new pty behind the same link; playback resumes."""
        self._call("replug")

    def pause(self) -> None:
        """Stop sending (the port stays, the reader sees a stall) until ``resume``."""
        self._call("pause")

    def resume(self) -> None:
        self._call("resume")

    def stop(self) -> None:
        """Stop playing, close the pty, remove the link. Safe to call twice."""
        if self._thread is None:
            self._close_pty()
            return
        self._call("stop")
        self._thread.join(timeout=5.0)
        self._thread = None

    def unread_bytes(self) -> int:
        """Bytes written into the pty that the reader has not taken yet."""
        return self._call("inq")

    def wait_drained(self, timeout: float) -> bool:
        """Wait until the reader has taken everything written (or ``timeout``)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if not self.plugged or self.unread_bytes() == 0:
                return True
            time.sleep(0.02)
        return False

    def __enter__(self) -> BoardEmulator:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # --- the writer thread ---------------------------------------------------

    def _call(self, op: Literal["unplug", "replug", "pause", "resume", "stop", "inq"]) -> int:
        request = _Request(op)
        if self._thread is None or not self._thread.is_alive():
            self._execute(request)  # not running: nothing can race us
            return request.result
        self._requests.put(request)
        self._wake.set()
        if not request.done.wait(timeout=5.0):
            msg = f"board emulator did not answer {op!r} within 5 s"
            raise EmulatorError(msg)
        return request.result

    def _execute(self, request: _Request) -> None:
        if request.op == "unplug" and self.plugged:
            self._drop_pending("unplugged")
            self._close_pty()
            self.stats.unplugs += 1
        elif request.op == "replug" and not self.plugged and not self._stopping:
            self._open_pty()
            self._base_ns = None  # resume paced from now, not in a burst
            self.stats.replugs += 1
        elif request.op in ("pause", "resume"):
            self._paused = request.op == "pause"
            self._base_ns = None
        elif request.op == "stop":
            self._stopping = True
            self._close_pty()
        elif request.op == "inq":
            request.result = self._follower_inq()
        request.done.set()

    def _run(self) -> None:
        try:
            while True:
                while not self._requests.empty():
                    self._execute(self._requests.get_nowait())
                if self._stopping:
                    break
                if not self._may_send():
                    self._sleep(0.05)
                elif self._pending:
                    self._write_some()
                else:
                    self._next_record()
        finally:
            self._close_pty()
            while not self._requests.empty():
                self._requests.get_nowait().done.set()

    def _may_send(self) -> bool:
        if not self.plugged or self._paused or self.finished.is_set():
            return False
        if not self._reader_present():
            self._reader_since = None
            self._base_ns = None  # resume paced from when a reader comes back
            return False
        if self._reader_since is None:
            self._reader_since = time.monotonic()
        return time.monotonic() - self._reader_since >= self.settle_s

    def _reader_present(self) -> bool:
        # The leader reports a hang-up while no process has the follower open.
        assert self._leader is not None
        poller = select.poll()
        poller.register(self._leader, select.POLLHUP)
        return not any(ev & select.POLLHUP for _, ev in poller.poll(0))

    def _sleep(self, seconds: float) -> None:
        self._wake.wait(min(seconds, 0.25))
        self._wake.clear()

    def _next_record(self) -> None:
        if self._index >= len(self.records):
            if not self.loop:
                self.finished.set()
                return
            self.stats.loops_completed += 1
            self._index = 0
            if self._rewriter is not None:
                self._rewriter.loop = self.stats.loops_completed
            # The next loop starts one mean record interval after the last record.
            if self._base_ns is not None:
                self._base_ns += self._scaled(self._loop_ns())
        t_ns, data = self.records[self._index]
        now = time.monotonic_ns()
        if self.speed != "max":
            offset = self._scaled(t_ns - self.records[0][0])
            if self._base_ns is None:
                self._base_ns = now - offset
            due = self._base_ns + offset
            if due > now:
                self._sleep(min((due - now) / 1e9, _POLL_S))
                return
        self._index += 1
        if self._rewriter is not None:
            data = self._rewriter.rewrite(data)
            if not data:
                return  # a packet's start only: it goes out with the record that ends it
        line = self.line
        if line is not None:
            changed = line(data)
            if changed is None:
                self.stats.records_lost += 1
                return
            data = changed
        self._pending = memoryview(data)
        self._deadline = time.monotonic() + self.write_timeout_s

    def _scaled(self, delta_ns: int) -> int:
        return 0 if self.speed == "max" else round(delta_ns / self.speed)

    def _write_some(self) -> None:
        leader = self._leader
        assert leader is not None  # plugged
        # poll(), not select(): select() refuses descriptors from 1024 up (many devices).
        poller = select.poll()
        poller.register(leader, select.POLLOUT)
        if poller.poll(_POLL_S * 1e3):
            try:
                n = os.write(leader, self._pending)
            except BlockingIOError:
                n = 0
            except OSError as exc:
                self._drop_pending(f"write failed: {exc}")
                return
            self.stats.bytes_written += n
            self._pending = self._pending[n:]
            if not self._pending:
                self.stats.records_written += 1
                return
        if time.monotonic() > self._deadline:
            self._drop_pending("the reader is not reading")

    def _drop_pending(self, why: str) -> None:
        if self._pending:
            log.debug("board emulator dropped %d bytes: %s", len(self._pending), why)
            self.stats.records_dropped += 1
            self.stats.bytes_dropped += len(self._pending)
            self._pending = memoryview(b"")

    # --- the pty and the link ---------------------------------------------

    def _check_link_free(self) -> None:
        if self.link.exists() and not self.link.is_symlink():
            msg = f"{self.link} exists and is not a symlink; refusing to replace it"
            raise EmulatorError(msg)
        if not self.link.parent.is_dir():
            msg = f"{self.link.parent}: no such directory for the link"
            raise EmulatorError(msg)

    def _open_pty(self) -> None:
        leader, follower = os.openpty()
        tty.setraw(follower, termios.TCSANOW)  # 8-bit clean, no echo, no line editing
        os.set_blocking(leader, False)
        device = os.ttyname(follower)
        os.close(follower)  # the settings stay with the pty; an open follower would hide readers
        tmp = self.link.with_name(f".{self.link.name}.{os.getpid()}.tmp")
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        os.symlink(device, tmp)
        os.replace(tmp, self.link)  # atomic: a reader never sees a half-made link
        self._leader, self._device = leader, device
        self._reader_since = None
        log.debug("board emulator: %s -> %s", self.link, device)

    def _close_pty(self) -> None:
        if self._device is not None:
            with contextlib.suppress(FileNotFoundError):
                if self.link.is_symlink() and os.readlink(self.link) == self._device:
                    self.link.unlink()
        if self._leader is not None:
            with contextlib.suppress(OSError):
                os.close(self._leader)
        self._leader = None
        self._device = None

    def _follower_inq(self) -> int:
        if self._device is None or not self._reader_present():
            return 0  # without a reader, nothing written is waiting for one
        fd = os.open(self._device, os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK)
        try:
            buf = bytearray(4)
            fcntl.ioctl(fd, termios.FIONREAD, buf)
        finally:
            os.close(fd)
        return int.from_bytes(buf, "little")
