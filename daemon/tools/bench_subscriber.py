"""The bench's subscriber: what a consumer of the pose topic sees, cheaply.

A paho client on its own thread takes every pose and keeps, per message, the
daemon's ``latency_ms`` (last byte -> publish), the receipt time minus the
frame's last byte (``predicted_for_mono_ns`` - 1/16 s, the same host clock)
and which of the model's "does not know" flags it carries. Those three fields
are read with byte searches, not a JSON parse of the 19 keypoints: at 128
pairs the subscriber takes 2,048 poses a second on the host it measures, and
its cost is the bench's, not the daemon's (the bench prints it apart).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import re
import threading
import time
from dataclasses import dataclass, field
from typing import Final

import paho.mqtt.client as paho
from paho.mqtt.enums import CallbackAPIVersion
from scotti.daemon.tools.bench_boards import PERIOD_NS
from scotti.daemon.tools.local_broker import Mosquitto

READY_TIMEOUT_S: Final = 120.0  # longest wait for every pair's first pose (a loaded host is slow)
OOD_FLAGS: Final = ("out_of_range", "unloaded", "unfamiliar")  # the schema's WithheldFlag
_PREDICTED_FOR = re.compile(rb'"predicted_for_mono_ns"\s*:\s*(\d+)')
_LATENCY = re.compile(rb'"latency_ms"\s*:\s*([-+0-9.eE]+)')
_FLAGS = re.compile(rb'"flags"\s*:\s*\[([^\]]*)\]')
_FLAG_BYTES: Final = tuple(f'"{f}"'.encode() for f in OOD_FLAGS)


def read_pose(payload: bytes | bytearray) -> tuple[int, float, int]:
    """(predicted_for_mono_ns, latency_ms, flag bits: 1 << OOD_FLAGS index) of a JSON
    pose; the fields found by byte search, a full parse only when one is missing."""
    when, latency = _PREDICTED_FOR.search(payload), _LATENCY.search(payload)
    if when is None or latency is None:  # another layout than the daemon's: parse it
        pose = json.loads(payload)
        flags = pose.get("flags", [])
        bits = sum(1 << i for i, f in enumerate(OOD_FLAGS) if f in flags)
        return int(pose["predicted_for_mono_ns"]), float(pose["latency_ms"]), bits
    bits = 0
    listed = _FLAGS.search(payload)
    if listed is not None and listed.group(1):
        text = listed.group(1)
        bits = sum(1 << i for i, f in enumerate(_FLAG_BYTES) if f in text)
    return int(when.group(1)), float(latency.group(1)), bits


@dataclass
class Poses:
    """What the subscriber kept in the measured seconds, one entry per pose."""

    publish: list[float] = field(default_factory=list)  # the daemon's latency_ms
    receipt: list[float] = field(default_factory=list)  # last byte -> subscriber, ms
    flagged: list[int] = field(default_factory=lambda: [0] * len(OOD_FLAGS))

    def __len__(self) -> int:
        return len(self.publish)

    def shares(self) -> dict[str, float]:
        """Per flag, the share (0..1) of the measured poses that carried it."""
        n = max(1, len(self.publish))
        return {f: c / n for f, c in zip(OOD_FLAGS, self.flagged, strict=True)}


class PoseSubscriber:
    """Subscribes to ``topic`` and measures for ``seconds`` once ready: ``warmup``
    seconds after the subscription or, with ``pairs``, after that many devices have
    each published their first pose (the daemon up, every window filled); sets
    ``measuring`` then. ``run`` returns at the end even while no pose comes."""

    def __init__(
        self,
        broker: Mosquitto,
        seconds: float,
        warmup: float,
        topic: str = "scotti/+/pose",
        *,
        pairs: int = 0,
        measuring: threading.Event | None = None,
    ) -> None:
        self.broker, self.topic, self.pairs = broker, topic, pairs
        self.seconds, self.warmup = seconds, warmup
        self.measuring = measuring if measuring is not None else threading.Event()
        self.poses = Poses()
        self._seen: set[str] = set()
        self._begin = self._end = math.inf  # set by ``run``, moved once every pair is ready
        self._done = threading.Event()

    def run(self) -> Poses:
        client = paho.Client(CallbackAPIVersion.VERSION2, protocol=paho.MQTTv5)
        client.on_message = self._on_message
        self._begin = time.monotonic() + (READY_TIMEOUT_S if self.pairs else self.warmup)
        self._end = self._begin + self.seconds
        client.connect(self.broker.host, self.broker.port)
        client.subscribe(self.topic)
        client.loop_start()
        try:
            while not self._done.is_set():  # ``_end`` moves once every pair is ready
                left = self._end - time.monotonic()
                if left <= 0:
                    break
                self._done.wait(min(0.2, left))
        finally:
            self._done.set()  # the callback keeps nothing more
            client.disconnect()
            client.loop_stop()
            self.measuring.set()  # never ready: the sampler must not wait forever
        return self.poses

    def _on_message(self, _c: paho.Client, _u: object, m: paho.MQTTMessage) -> None:
        received = time.monotonic_ns()
        if self._done.is_set():
            return
        now = received / 1e9
        if self.pairs and len(self._seen) < self.pairs:
            self._seen.add(m.topic)
            if len(self._seen) == self.pairs:  # all ready: measure after the warm-up
                self._begin, self._end = now + self.warmup, now + self.warmup + self.seconds
        if now >= self._end:
            self._done.set()
            return
        if now < self._begin:
            return
        self.measuring.set()
        when, latency, bits = read_pose(m.payload)
        p = self.poses
        p.publish.append(latency)
        p.receipt.append((received - (when - PERIOD_NS)) / 1e6)
        if bits:
            for i in range(len(OOD_FLAGS)):
                if bits >> i & 1:
                    p.flagged[i] += 1


async def collect(
    broker: Mosquitto,
    seconds: float,
    warmup: float,
    topic: str = "scotti/+/pose",
    *,
    pairs: int = 0,
    measuring: threading.Event | None = None,
) -> list[dict[str, float]]:
    """Per pose: {"publish": latency_ms, "receipt": ms} for ``seconds`` (``PoseSubscriber``
    on a thread; for callers in an event loop)."""
    sub = PoseSubscriber(broker, seconds, warmup, topic, pairs=pairs, measuring=measuring)
    poses = await asyncio.to_thread(sub.run)
    return [{"publish": a, "receipt": b} for a, b in zip(poses.publish, poses.receipt, strict=True)]


def engine_frames_per_call(broker: Mosquitto, devices: int, wait_s: float = 1.5) -> float:
    """Frames per model call of the daemon's engine(s), from the devices' retained health
    (``pipeline.engine``; each worker process has its own engine): the mean over the
    devices, 0.0 when none said. Counted from the daemon's start: read after it stopped
    (its last health), the whole run's. Only the run's ``devices`` (pair00, pair01, ...):
    an earlier run's in the same broker may still be retained."""
    ours = {f"scotti/pair{i:02d}/health" for i in range(devices)}
    said: dict[str, float] = {}

    def on_message(_c: paho.Client, _u: object, m: paho.MQTTMessage) -> None:
        with contextlib.suppress(ValueError, TypeError, KeyError):
            if m.topic in ours:
                engine = json.loads(m.payload)["pipeline"]["engine"]
                said[m.topic] = float(engine["frames_per_call"])

    client = paho.Client(CallbackAPIVersion.VERSION2, protocol=paho.MQTTv5)
    client.on_message = on_message
    client.connect(broker.host, broker.port)
    client.subscribe("scotti/+/health")
    client.loop_start()
    try:
        time.sleep(wait_s)  # the retained ones come at once; a second for stragglers
    finally:
        client.disconnect()
        client.loop_stop()
    return sum(said.values()) / len(said) if said else 0.0
