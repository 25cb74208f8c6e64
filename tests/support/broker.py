"""Helpers for tests that talk to a real broker: collect messages, run the daemon."""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import aiomqtt
from scotti.daemon.tools.local_broker import Mosquitto


@dataclass(frozen=True)
class Received:
    topic: str
    payload: bytes
    retain: bool
    content_type: str | None
    expiry: int | None
    at: float  # time.monotonic() on arrival


@dataclass
class Collector:
    """Subscribes in a background thread; ``messages`` grows as they arrive."""

    broker: Mosquitto
    topic_filter: str
    messages: list[Received] = field(default_factory=list)
    _lock: threading.Lock = field(default_factory=threading.Lock)
    _stop: threading.Event = field(default_factory=threading.Event)
    _subscribed: threading.Event = field(default_factory=threading.Event)
    _loop: asyncio.AbstractEventLoop | None = None
    _task: asyncio.Task[None] | None = None

    def snapshot(self, suffix: str | None = None) -> list[Received]:
        with self._lock:
            msgs = list(self.messages)
        return [m for m in msgs if suffix is None or m.topic.endswith("/" + suffix)]

    def wait_for(
        self, predicate: Callable[[list[Received]], bool], timeout: float, what: str = ""
    ) -> list[Received]:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            msgs = self.snapshot()
            if predicate(msgs):
                return msgs
            time.sleep(0.05)
        last = [(m.topic, m.payload[:200]) for m in self.snapshot()[-5:]]
        msg = f"timed out after {timeout} s waiting for {what or predicate}; last: {last}"
        raise AssertionError(msg)

    async def _run(self) -> None:
        while not self._stop.is_set():
            try:
                user, password = self.broker.credentials or (None, None)
                async with aiomqtt.Client(
                    self.broker.host,
                    self.broker.port,
                    username=user,
                    password=password,
                    protocol=aiomqtt.ProtocolVersion.V5,
                ) as client:
                    await client.subscribe(self.topic_filter, qos=1)
                    self._subscribed.set()
                    async for m in client.messages:
                        props = m.properties
                        ct = getattr(props, "ContentType", None)
                        expiry = getattr(props, "MessageExpiryInterval", None)
                        rec = Received(
                            str(m.topic), bytes(m.payload), m.retain, ct, expiry, time.monotonic()
                        )
                        with self._lock:
                            self.messages.append(rec)
                        if self._stop.is_set():
                            return
            except aiomqtt.MqttError:
                await asyncio.sleep(0.2)

    def _thread_main(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        self._task = loop.create_task(self._run())
        with contextlib.suppress(asyncio.CancelledError):
            loop.run_until_complete(self._task)
        loop.close()

    def close(self) -> None:
        self._stop.set()
        if self._loop is not None and self._task is not None:
            with contextlib.suppress(RuntimeError):  # loop already closed
                self._loop.call_soon_threadsafe(self._task.cancel)


@contextlib.contextmanager
def collect(broker: Mosquitto, topic_filter: str = "#") -> Iterator[Collector]:
    """Collect every message matching ``topic_filter`` while the block runs."""
    collector = Collector(broker, topic_filter)
    thread = threading.Thread(target=collector._thread_main, daemon=True)
    thread.start()
    if not collector._subscribed.wait(10):
        collector.close()
        msg = "collector could not subscribe"
        raise AssertionError(msg)
    try:
        yield collector
    finally:
        collector.close()
        thread.join(10)


@dataclass
class DaemonProcess:
    """``scotti-daemon`` run as a subprocess, its stderr kept in a file."""

    proc: subprocess.Popen[bytes]
    log_path: Path

    @property
    def log(self) -> str:
        return self.log_path.read_text(errors="replace")

    def wait(self, timeout: float) -> int:
        try:
            return self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(5)
            msg = f"scotti-daemon still running after {timeout} s; log:\n{self.log[-3000:]}"
            raise AssertionError(msg) from None

    def stop(self) -> int:
        """SIGTERM, as systemd stops it; returns the exit status."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        return self.wait(15)


def start_daemon(
    args: list[str], log_path: Path, env: dict[str, str] | None = None
) -> DaemonProcess:
    """Start ``scotti-daemon ARGS`` with SCOTTI_* from the parent cleared (plus ``env``)."""
    clean = {k: v for k, v in os.environ.items() if not k.startswith("SCOTTI_")}
    clean.pop("NOTIFY_SOCKET", None)
    exe = Path(sys.executable).with_name("scotti-daemon")
    with log_path.open("wb") as log:
        proc = subprocess.Popen(
            [str(exe), *args], stdout=log, stderr=subprocess.STDOUT, env={**clean, **(env or {})}
        )
    return DaemonProcess(proc, log_path)


def payloads(msgs: list[Received], name: str) -> list[dict[str, Any]]:
    """JSON payloads of the messages on topics ending in ``/name``, in arrival order."""
    return [json.loads(m.payload) for m in msgs if m.topic.endswith("/" + name)]
