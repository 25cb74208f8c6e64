"""The fault soak's eyes: a subscriber on the daemon's topics that answers questions.

Keeps ``status``, ``pose`` and ``health`` messages with their arrival time
(``time.monotonic()``), reconnects within tens of milliseconds when the broker
comes back, and answers what the soak asks between faults: is the daemon
online since ``t``, has a prediction arrived since, which seqs are missing.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Final

import aiomqtt
from scotti.daemon.tools.local_broker import Mosquitto

KEPT: Final = ("status", "pose", "health")
RETRY_S: Final = 0.02  # the watcher must be back before the daemon (backoff >= 0.25 s)


@dataclass(frozen=True)
class Seen:
    at: float  # time.monotonic() on arrival
    name: str  # status, pose or health
    payload: dict[str, Any]


class Watcher:
    def __init__(self, broker: Mosquitto, topic_filter: str) -> None:
        self.broker = broker
        self.topic_filter = topic_filter
        self.messages: list[Seen] = []  # since the mark
        self._mark = 0.0
        self._seq_before_mark: int | None = None  # the newest pose seq before the mark
        self._connected = asyncio.Event()
        self._changed = asyncio.Event()

    async def run(self) -> None:
        while True:
            try:
                async with aiomqtt.Client(
                    self.broker.host, self.broker.port, protocol=aiomqtt.ProtocolVersion.V5
                ) as client:
                    await client.subscribe(self.topic_filter, qos=1)
                    self._connected.set()
                    async for m in client.messages:
                        name = str(m.topic).rsplit("/", 1)[-1]
                        if name in KEPT and isinstance(m.payload, bytes | bytearray):
                            payload = json.loads(m.payload)
                            self.messages.append(Seen(time.monotonic(), name, payload))
                            self._changed.set()
            except aiomqtt.MqttError:
                self._connected.clear()
                await asyncio.sleep(RETRY_S)

    async def wait_connected(self, within_s: float) -> None:
        async with asyncio.timeout(within_s):
            await self._connected.wait()

    async def until(self, predicate: Callable[[], bool], within_s: float, what: str) -> None:
        """Return once ``predicate()`` holds; else ``TimeoutError`` naming ``what``."""
        deadline = time.monotonic() + within_s
        while not predicate():
            left = deadline - time.monotonic()
            if left <= 0:
                msg = f"{what}: not within {within_s:g} s"
                raise TimeoutError(msg)
            self._changed.clear()
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(min(left, 0.1)):
                    await self._changed.wait()

    # --- questions ---------------------------------------------------------------------------
    def _since(self, name: str, t: float) -> list[Seen]:
        return [m for m in self.messages if m.name == name and m.at >= t]

    def online_since(self, t: float) -> bool:
        statuses = self._since("status", t)
        if not statuses:
            return False
        last = statuses[-1].payload
        # A withheld prediction (unloaded, out_of_range, unfamiliar) degrades status
        # with its reason; the pipeline itself is up.
        ood = ("unloaded:", "out_of_range:", "unfamiliar:")
        reasons = last.get("reasons") or []
        return last.get("state") == "online" or (
            last.get("state") == "degraded" and all(str(r).startswith(ood) for r in reasons)
        )

    def pose_since(self, t: float) -> bool:
        return bool(self._since("pose", t))

    def first_pose_since(self, t: float) -> float | None:
        poses = self._since("pose", t)
        return poses[0].at if poses else None

    def drained_since(self, t: float) -> bool:
        """Has a health report since ``t`` said no prediction waits to be published?"""
        return any(m.payload.get("queue_depth") == 0 for m in self._since("health", t))

    def reason_since(self, text: str) -> bool:
        """Has a status since the mark given a reason containing ``text``?"""
        return any(
            any(text in r for r in m.payload.get("reasons", ()))
            for m in self._since("status", self._mark)
        )

    def poses_after_disconnect(self) -> int:
        """Poses that arrived after the first "receiver disconnected" status since the mark."""
        cut = next(
            (
                m.at
                for m in self._since("status", self._mark)
                if any("receiver disconnected" in r for r in m.payload.get("reasons", ()))
            ),
            None,
        )
        return 0 if cut is None else len([m for m in self._since("pose", cut) if m.at > cut])

    def missing_seqs(self) -> int:
        """Seqs missing among the poses since the mark (from the last one before it)."""
        seqs = [int(m.payload["seq"]) for m in self._since("pose", self._mark)]
        if self._seq_before_mark is not None:
            seqs.insert(0, self._seq_before_mark)
        return sum(max(0, b - a - 1) for a, b in itertools.pairwise(seqs))

    def forget_before(self, t: float) -> None:
        """Start a new mark at ``t``: older messages go, the newest pose seq is remembered."""
        poses = [m for m in self.messages if m.name == "pose" and m.at < t]
        if poses:
            self._seq_before_mark = int(poses[-1].payload["seq"])
        self.messages = [m for m in self.messages if m.at >= t]
        self._mark = t
