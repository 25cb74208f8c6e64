"""The daemon's side of a network output's own process (``front.py``).

``FrontProcess.start`` binds the public socket here (so that a port in use
is the daemon's one-line error, before anything runs), hands it to a new
``python -m scotti.daemon.outputs.front`` with a SOCK_SEQPACKET socket pair
for messages, and closes its own copy: from then on every client's
descriptor lives in that process. Messages to it are sent without waiting
(a full channel drops a frame, counted); what it says back (which devices
have readers, its counters, its log records) is read on a thread of ours
that sleeps in ``recv``.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
import secrets
import select
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Mapping
from typing import Any, Final

from scotti.daemon.outputs import OutputError, guard
from scotti.daemon.outputs.front import END, HEADER, STATUS

log = logging.getLogger(__name__)

STOP_WAIT_S: Final = 3.0  # for the process to end by itself, before it is killed
STATUS_WAIT_S: Final = 1.0  # a status is never dropped: a full channel is waited on this long


def listen(host: str, port: int, what: str) -> socket.socket:
    """The public socket, bound and listening; ``OutputError`` (one line) when it cannot."""
    try:
        family, kind, proto, _, address = socket.getaddrinfo(
            host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE
        )[0]
        sock = socket.socket(family, kind, proto)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind(address)
            sock.listen(128)
        except BaseException:
            sock.close()
            raise
    except OSError as exc:
        msg = f"{what}: cannot listen on {host}:{port}: {exc.strerror or exc}"
        raise OutputError(msg) from None
    return sock


def hidden_loopback() -> str:
    """A loopback address for a server only the gate may reach (the Foxglove SDK's, which
    checks no Origin, Host or token): a random one of 127.0.0.0/8, not 127.0.0.1, where
    the host takes it (Linux does). A web page in a local browser can open WebSockets to
    127.0.0.1 and scan its ports; 2^24 addresses times their ports it cannot. Where the
    host has only 127.0.0.1 (macOS), 127.0.0.1."""
    for _ in range(4):
        a, b = secrets.randbelow(256), secrets.randbelow(256)
        host = f"127.{a}.{b}.{2 + secrets.randbelow(253)}"  # never .0, .1 or .255
        with contextlib.suppress(OSError), socket.socket() as probe:
            probe.bind((host, 0))
            return host
    return "127.0.0.1"


class FrontProcess:
    """One output's server process: started, fed, read back and stopped from here."""

    def __init__(self, name: str, proc: subprocess.Popen[bytes], channel: socket.socket) -> None:
        self.name = name
        self.proc = proc
        self.channel = channel
        self.watched: frozenset[int] = frozenset()  # devices with a reader (web only)
        self.counters: dict[str, Any] = {
            "connections": 0,
            "max_connections": 0,
            "refused": dict.fromkeys(guard.REASONS, 0),
            "dropped": 0,
        }
        self.unsent = 0  # frames the channel had no room for (the process fell behind)
        self.changed = threading.Condition()  # notified on every message it sends
        self._closing = False
        self._reader = threading.Thread(target=self._read, name=f"scotti-{name}", daemon=True)
        self._reader.start()

    @classmethod
    def start(
        cls, name: str, listener: socket.socket, rules: guard.Rules, config: Mapping[str, Any]
    ) -> FrontProcess:
        """``config``: the mode's own (``mode`` = ``web`` or ``proxy`` and what it needs)."""
        ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        settings = {
            **config,
            "name": name,
            "host": rules.bound_host,
            "max_connections": rules.max_connections,
            "allowed_hosts": list(rules.allowed_hosts),
            "allowed_origins": list(rules.allowed_origins),
            "token": rules.token,
            "listen_fd": listener.fileno(),
            "channel_fd": theirs.fileno(),
        }
        try:
            proc = subprocess.Popen(
                [sys.executable, "-m", "scotti.daemon.outputs.front"],
                stdin=subprocess.PIPE,
                pass_fds=(listener.fileno(), theirs.fileno()),
                env={**os.environ, "PYTHONUNBUFFERED": "1"},
            )
            assert proc.stdin is not None
            with proc.stdin:  # the token goes this way: never on a command line
                proc.stdin.write(json.dumps(settings).encode())
        except OSError as exc:
            ours.close()
            msg = f"{name}: cannot start its server process: {exc.strerror or exc}"
            raise OutputError(msg) from None
        finally:
            listener.close()  # the process holds it now
            theirs.close()
        ours.setblocking(True)
        return cls(name, proc, ours)

    def send(self, kind: bytes, device: int, payload: bytes) -> bool:
        """A frame to the process without waiting: False (and counted) when it has no room."""
        try:
            self.channel.send(HEADER.pack(kind, device) + payload, socket.MSG_DONTWAIT)
        except BlockingIOError:
            self.unsent += 1
            return False
        except OSError:  # the process is gone: said once by the reader
            return False
        return True

    def send_status(self, device: int, status: Mapping[str, Any]) -> None:
        """A status waits for room (briefly): the view must not keep a stale one."""
        message = HEADER.pack(STATUS, device) + json.dumps(status).encode()
        deadline = time.monotonic() + STATUS_WAIT_S
        while True:
            try:
                self.channel.send(message, socket.MSG_DONTWAIT)
                return
            except BlockingIOError:
                left = deadline - time.monotonic()
                if left <= 0:
                    self.unsent += 1
                    return
                poller = select.poll()  # select() refuses descriptors from 1024 up
                poller.register(self.channel, select.POLLOUT)
                poller.poll(left * 1e3)
            except OSError:  # the process is gone: said once by the reader
                return

    def wait_for(self, check: Any, timeout_s: float) -> bool:
        """Until ``check(self)`` holds (re-checked on each message), or False after
        ``timeout_s`` (the tests' way to wait on the process, not a sleep)."""
        with self.changed:
            return bool(self.changed.wait_for(lambda: check(self), timeout_s))

    async def close(self) -> None:
        self._closing = True
        with contextlib.suppress(OSError):
            self.channel.send(HEADER.pack(END, 0), socket.MSG_DONTWAIT)
        try:
            await asyncio.to_thread(self.proc.wait, STOP_WAIT_S)
        except subprocess.TimeoutExpired:
            log.warning("%s: its server process did not end; killed", self.name)
            self.proc.kill()
            await asyncio.to_thread(self.proc.wait)
        with contextlib.suppress(OSError):
            self.channel.shutdown(socket.SHUT_RDWR)
        await asyncio.to_thread(self._reader.join, STOP_WAIT_S)
        self.channel.close()

    def _read(self) -> None:
        while True:
            try:
                data = self.channel.recv(1 << 16)
            except OSError:
                data = b""
            if not data:
                break
            try:
                message = json.loads(data)
            except ValueError:
                continue
            self._take(message)
        if not self._closing:
            log.warning(
                "%s: its server process ended (exit %s): the output serves no one now",
                self.name,
                self.proc.poll(),
            )
        with self.changed:
            self.changed.notify_all()

    def _take(self, message: dict[str, Any]) -> None:
        if "log" in message:
            level, name, text = message["log"]
            logging.getLogger(name).log(int(level), "%s", text)
        with self.changed:
            if "watched" in message:
                self.watched = frozenset(message["watched"])
            if "counters" in message:
                self.counters = message["counters"]
            self.changed.notify_all()
