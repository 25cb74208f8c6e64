"""MQTT publishing: one reusable aiomqtt client in a reconnect loop.

The pipeline hands over one ``FrameBatch`` per prediction through a bounded
queue that drops the oldest (the reader never waits for the broker). The
loop here connects (also when the broker is down at boot: it keeps
retrying with backoff), republishes the retained ``status`` and ``info`` on
every connect, then publishes batches as they come. Each status change is
published in order, and never before the predictions submitted ahead of it (a
consumer that reads "receiver disconnected" gets no older pose after it);
after a reconnect only the current status goes out. Health is "latest wins"
and may overtake predictions.

A broker that goes away, restarts or refuses (bad password, unknown CA) is
one WARNING line with the reason, then retries with backoff until it is back
(one INFO line), said again every ``outage_warning_s`` (15 s) while it stays
away; never an ERROR, never a traceback. A status is said in the log only
once the broker has acknowledged it (``on_status_published``).

Pattern: aiomqtt docs/reconnection.md (one ``Client``, ``async with`` in a loop).
"""

from __future__ import annotations

import asyncio
import collections
import logging
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import Any, Final, Literal

import aiomqtt
import paho.mqtt.client as paho
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties
from pydantic import BaseModel
from scotti.daemon.mqtt.latency_slot import LatencySlot
from scotti.daemon.mqtt.schemas import CONTENT_TYPES, Health, Info, Status, encode
from scotti.daemon.service.counters import LatencyRing
from scotti.daemon.settings.mqtt import MqttSettings
from scotti.daemon.waiting import Backoff, wait_event

log = logging.getLogger(__name__)

BACKOFF_START_S: Final = 0.25
RETAINED_QOS: Final = 1  # status/info/health: must arrive, late is fine
NUDGE_AFTER_S: Final = 0.5  # a publish not written by then: write paho's queue directly
MAX_PENDING_STATUSES: Final = 16  # status changes kept while the broker is slow or away
FRAME_QOS: Final = 0  # pose/action/progress: a newer one is 62 ms away
DROP_LOG_EVERY_S: Final = 10.0  # a full queue is logged at most this often (and counted)


@dataclass(frozen=True)
class FrameBatch:
    """What one prediction publishes; rendered at publish time (a prediction dropped
    from the queue costs no encoding)."""

    seq: int
    last_byte_mono_ns: int  # 0 when unknown: latency is then measured from inference
    made_mono_ns: int  # when the prediction was made
    # latency_ms -> (topic, payload); called once, with 0.0: the publisher writes the
    # true latency into the encoded bytes as they leave (``LatencySlot``).
    render: Callable[[float], list[tuple[str, BaseModel]]]


@dataclass
class PublisherStats:
    published: int = 0  # predictions fully published
    dropped_full: int = 0  # pushed out of the queue by newer ones
    dropped_stale: int = 0  # older than the message expiry when the broker came back
    dropped_error: int = 0  # lost in a publish that failed
    connects: int = 0
    last_error: str = ""  # why the broker connection last failed, one line
    outages: int = 0  # times the broker was found away (at start, or lost)
    unreachable_s: float = 0.0  # seconds without the broker, over the outages that ended
    last_seq: int | None = None
    latency_ms: LatencyRing = field(default_factory=LatencyRing)  # last byte -> publish

    @property
    def dropped(self) -> int:
        return self.dropped_full + self.dropped_stale + self.dropped_error

    @property
    def reconnects(self) -> int:
        return max(0, self.connects - 1)


BrokerState = Literal["connecting", "connected", "disconnected", "stopped"]


class Publisher:
    """Owns the MQTT client; everything else only calls the non-blocking setters."""

    def __init__(self, settings: MqttSettings, info: Info, will: Status) -> None:
        self.settings = settings
        self.stats = PublisherStats()
        self.state: BrokerState = "connecting"
        self.on_state_change: Callable[[BrokerState, str], None] = lambda _s, _r: None
        self.on_drained: Callable[[], None] = lambda: None  # at stop, queue empty
        # A status the broker has acknowledged (PUBACK): only then is it said in the log.
        self.on_status_published: Callable[[Status], None] = lambda _s: None
        # Predictions older than the message expiry when the broker is back are dropped
        # (live); a replay, which waits for the broker, sends them all (False).
        self.drop_stale = True
        self._down_since: float | None = None  # monotonic start of the current outage
        self._warned_at = 0.0  # the last outage WARNING
        self._source_waiting = False  # a replay is held in ``wait_room`` now
        self._said_source_waits = False  # ... and the log said so in this outage
        self._fmt = settings.format
        self._info = info
        self._status: Status | None = None
        self._health: Health | None = None
        # Status changes not yet published: (batches submitted before it, status), in order.
        self._statuses: collections.deque[tuple[int, Status]] = collections.deque(
            maxlen=MAX_PENDING_STATUSES
        )
        self._health_dirty = False
        self._queue: collections.deque[FrameBatch] = collections.deque()
        self._submitted = 0  # batches ever submitted
        self._drop_logged_at = -DROP_LOG_EVERY_S  # the first drop is logged at once
        self._wake = asyncio.Event()
        self._room = asyncio.Event()  # set whenever a batch leaves the queue
        v5 = settings.protocol == "5"  # MQTT 3.1.1 has no properties: none are sent
        self._frame_props = _properties(self._fmt, settings.message_expiry_s) if v5 else None
        self._retained_props = _properties(self._fmt, None) if v5 else None
        health_expiry = max(1, round(3 * settings.health_interval_s))
        self._health_props = _properties(self._fmt, health_expiry) if v5 else None
        self._client = aiomqtt.Client(
            settings.host,
            settings.port,
            username=settings.username,
            password=settings.password.get_secret_value() if settings.password else None,
            identifier=settings.client_id or f"scotti-daemon-{settings.device_id}",
            protocol=aiomqtt.ProtocolVersion.V5 if v5 else aiomqtt.ProtocolVersion.V311,
            will=aiomqtt.Will(
                settings.topic("status"),
                encode(will, self._fmt),
                qos=RETAINED_QOS,
                retain=True,
                properties=self._retained_props,
            ),
            keepalive=settings.keepalive_s,
            timeout=5,
            tls_context=settings.tls_context(),
            logger=logging.getLogger("scotti.daemon.mqtt"),
        )

    # --- called from the pipeline's side (event loop thread, never blocks) ---
    @property
    def queue_depth(self) -> int:
        return len(self._queue)

    def submit(self, batch: FrameBatch) -> None:
        if len(self._queue) >= self.settings.queue_size:
            self._queue.popleft()
            self.stats.dropped_full += 1
            self._log_drop()
        self._queue.append(batch)
        self._submitted += 1
        self._wake.set()

    def _log_drop(self) -> None:
        """A live source never waits: the oldest prediction goes, counted in health
        (publish.dropped_queue_full) and said here, at most once per DROP_LOG_EVERY_S."""
        now = time.monotonic()
        if now - self._drop_logged_at < DROP_LOG_EVERY_S:
            return
        self._drop_logged_at = now
        why = (
            "the broker is unreachable"
            if self.state == "disconnected"
            else "the broker or this host is slower than the insoles"
        )
        log.warning(
            "publish queue full (%d): dropped the oldest prediction (%d so far); %s",
            self.settings.queue_size,
            self.stats.dropped_full,
            why,
        )

    async def wait_room(self, margin: int) -> None:
        """Wait until the queue has room for ``margin`` more batches (a replay waits
        here instead of having its predictions pushed out of a full queue)."""
        limit = max(0, self.settings.queue_size - margin)
        while len(self._queue) > limit:
            self._room.clear()
            self._source_waiting = True
            self._say_source_waits()
            try:
                await self._room.wait()
            finally:
                self._source_waiting = False

    def _say_source_waits(self) -> None:
        """Once per outage, while a replay is held back: it is not stuck, it waits."""
        if self.state != "disconnected" or self._said_source_waits:
            return
        self._said_source_waits = True
        log.warning(
            "the replay waits for the broker %s: nothing is dropped, it goes on when the "
            "broker takes messages again",
            self.settings.broker,
        )

    def set_status(self, status: Status) -> None:
        """Publish ``status`` (retained) after the predictions already submitted."""
        self._status = status
        self._statuses.append((self._submitted, status))
        self._wake.set()

    @property
    def detail(self) -> str:
        """The broker state in a few words, with the reason while disconnected."""
        if self.state == "disconnected" and self.stats.last_error:
            return f"disconnected ({self.stats.last_error})"
        return self.state

    def set_health(self, health: Health) -> None:
        self._health, self._health_dirty = health, True
        self._wake.set()

    # --- the connection loop ---------------------------------------------------
    async def run(self, stop: asyncio.Event) -> None:
        """Publish until ``stop``; then drain the queue, call ``on_drained``, disconnect."""
        backoff = Backoff(BACKOFF_START_S, cap_s=self.settings.reconnect_max_s, jitter=0.0)
        while True:
            try:
                async with self._client:
                    # "connected" once the broker has taken a message, not at CONNACK: a
                    # connection that stalls at once stays part of the same outage (one
                    # WARNING), and the backoff starts afresh only after a working one.
                    await self._publish(self.settings.topic("info"), self._info, True)
                    self.stats.connects += 1
                    backoff.reset()
                    self._set_state("connected", self.settings.broker)
                    self._health_dirty = True
                    if self._status is not None:  # the current one, still after older frames
                        mark = self._statuses[-1][0] if self._statuses else 0
                        self._statuses = collections.deque(
                            [(mark, self._status)], maxlen=MAX_PENDING_STATUSES
                        )
                    await self._pump(stop)
                self._set_state("stopped", "")
                return
            except aiomqtt.MqttError as exc:
                self._set_state("disconnected", explain(exc))
            if stop.is_set():
                self._set_state("stopped", "")
                return
            await wait_event(stop, backoff.next_delay())

    async def _pump(self, stop: asyncio.Event) -> None:
        while True:
            self._wake.clear()
            await self._flush_retained()
            while self._queue:
                batch = self._queue.popleft()
                self._room.set()
                await self._publish_batch(batch)
                await self._flush_retained()  # status changes overtake a long backlog
            if stop.is_set():
                self.on_drained()  # the last health and status, after the last frame
                await self._flush_retained()
                return
            await _wait_any(self._wake, stop)

    async def _flush_retained(self) -> None:
        taken = self._submitted - len(self._queue)  # batches published or dropped
        while self._statuses and self._statuses[0][0] <= taken:
            status = self._statuses[0][1]
            await self._publish(self.settings.topic("status"), status, True)  # QoS 1: PUBACK
            self._statuses.popleft()
            self.on_status_published(status)
        if self._health_dirty and self._health is not None:
            self._health_dirty = False
            await self._publish(
                self.settings.topic("health"), self._health, True, self._health_props
            )

    async def _publish_batch(self, batch: FrameBatch) -> None:
        now = time.monotonic_ns()
        if self.drop_stale and now - batch.made_mono_ns > self.settings.message_expiry_s * 1e9:
            self.stats.dropped_stale += 1
            return
        origin = batch.last_byte_mono_ns or batch.made_mono_ns
        # Each payload is encoded once, its latency_ms left open and written in just
        # before the bytes go to the client (``LatencySlot``): the payload's age when
        # it leaves, encoding included. All of a prediction's messages are handed to
        # paho at once and go out in one write: one at a time, each would wait for its
        # own turn of the loop, and on a loaded host those turns, not the broker,
        # bound how many predictions go out.
        messages = [
            (self.settings.topic(name), LatencySlot.encode(payload, self._fmt))
            for name, payload in batch.render(0.0)
        ]
        try:
            # All but the last go straight into paho's queue; awaiting the last one's
            # write (aiomqtt) awaits theirs too: paho writes its queue in order. One
            # await per prediction, not a task, an event and a timeout per message
            # (a tenth of the event loop's time at 16 pairs, py-spy).
            for topic, slot in messages[:-1]:
                self._queue_frame(topic, slot, origin)
            if messages:
                await self._unless_lost(self._publish_frame(*messages[-1], origin))
        except aiomqtt.MqttError:
            self.stats.dropped_error += 1
            raise
        self.stats.published += 1
        self.stats.last_seq = batch.seq
        # health's end_to_end: up to the write to the socket (aiomqtt returns from a
        # QoS 0 publish once paho has written it).
        self.stats.latency_ms.add((time.monotonic_ns() - origin) / 1e6)

    def _queue_frame(self, topic: str, slot: LatencySlot, origin_ns: int) -> None:
        """Hand one per-frame message to paho without waiting for its write (QoS 0)."""
        latency_ms = (time.monotonic_ns() - origin_ns) / 1e6
        paho_client: paho.Client = self._client._client  # aiomqtt 2.x keeps paho here
        info = paho_client.publish(
            topic, slot.fill(latency_ms), qos=FRAME_QOS, retain=False, properties=self._frame_props
        )
        if info.rc != paho.MQTT_ERR_SUCCESS:  # not connected: as aiomqtt's publish says it
            raise aiomqtt.MqttCodeError(info.rc, "Could not publish message")

    async def _publish_frame(self, topic: str, slot: LatencySlot, origin_ns: int) -> None:
        latency_ms = (time.monotonic_ns() - origin_ns) / 1e6
        await self._client.publish(
            topic, slot.fill(latency_ms), qos=FRAME_QOS, retain=False, properties=self._frame_props
        )

    async def _publish(
        self, topic: str, payload: BaseModel, retained: bool, props: Properties | None = None
    ) -> None:
        publish = self._client.publish(
            topic,
            encode(payload, self._fmt),
            qos=RETAINED_QOS if retained else FRAME_QOS,
            retain=retained,
            properties=props if props is not None else self._retained_props,
        )
        if retained:
            await self._unless_lost(publish)
        else:
            await publish

    async def _unless_lost(self, publish: Awaitable[Any]) -> None:
        """Await publishes, or fail as soon as the connection is lost.

        aiomqtt waits for a PUBACK (QoS 1) or for the write (QoS 0) until its timeout
        (5 s) even when the broker is already gone; its disconnect future (private,
        aiomqtt 2.x) says so at once.
        """
        lost = getattr(self._client, "_disconnected", None)
        if not isinstance(lost, asyncio.Future):
            await publish
            return
        task = asyncio.ensure_future(publish)
        done, _ = await asyncio.wait(
            {task, lost}, timeout=NUDGE_AFTER_S, return_when=asyncio.FIRST_COMPLETED
        )
        if not done:
            self._nudge()
            await asyncio.wait({task, lost}, return_when=asyncio.FIRST_COMPLETED)
        if task.done():
            task.result()
            return
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        if not lost.cancelled():
            lost.exception()  # retrieved: it is reported below, not by asyncio at exit
        msg = "connection lost"
        raise aiomqtt.MqttError(msg)

    def _nudge(self) -> None:
        """Write paho's queued packets now.

        Seen in the fault soak: reconnects that took 6 s instead of 0.3, the first
        publish waiting out aiomqtt's 5 s timeout. The likely cause (not proven):
        aiomqtt asks the loop to watch the socket for writability through
        ``call_soon_threadsafe``, and around a reconnect that request can be lost
        (it races the old socket's), leaving the packets in paho's queue.
        """
        paho_client = getattr(self._client, "_client", None)
        if paho_client is not None:
            try:
                paho_client.loop_write()
            except Exception:  # the connection is gone after all: the publish will say so
                log.debug("loop_write after a stalled publish", exc_info=True)

    def _set_state(self, state: BrokerState, detail: str) -> None:
        if state == "disconnected":
            self.stats.last_error = detail
            self._warn_outage(detail)
        elif self._down_since is not None:  # the outage is over
            self.stats.unreachable_s += time.monotonic() - self._down_since
            self._down_since = None
        if state == self.state:
            return
        self.state = state
        if state == "connected":
            log.info("broker %s: connected", self.settings.broker)
            self._said_source_waits = False
        self.on_state_change(state, detail)
        if state == "disconnected" and self._source_waiting:
            self._say_source_waits()

    def _warn_outage(self, detail: str) -> None:
        """A WARNING when the broker is found away, then one every ``outage_warning_s``
        while it stays away (a daemon that waits in silence for a broker nobody started
        looks like one that works); the retries in between only at debug."""
        now = time.monotonic()
        broker, hint = self.settings.broker, _hint(detail, self.settings.port)
        if self._down_since is None:
            self._down_since = self._warned_at = now
            self.stats.outages += 1
            log.warning("broker %s: %s; retrying with backoff%s", broker, detail, hint)
        elif now - self._warned_at >= self.settings.outage_warning_s:
            self._warned_at = now
            log.warning(
                "broker %s: still unreachable after %.0f s (%s); retrying every %g s at most%s",
                broker,
                now - self._down_since,
                detail,
                self.settings.reconnect_max_s,
                hint,
            )
        else:
            log.debug("broker %s: %s; retrying with backoff", broker, detail)

    @property
    def unreachable_s(self) -> float:
        """Seconds without the broker so far, the current outage included."""
        now_down = time.monotonic() - self._down_since if self._down_since is not None else 0.0
        return self.stats.unreachable_s + now_down


_LOST: Final = (paho.MQTT_ERR_NO_CONN, paho.MQTT_ERR_CONN_LOST)


def _hint(detail: str, port: int) -> str:
    """What to do about a refused connection: nothing listens at that address."""
    if "refused" not in detail.lower():
        return ""
    return (
        "; is a broker running? (apt install mosquitto, or "
        f"python -m scotti.daemon.tools.local_broker --port {port})"
    )


def explain(exc: aiomqtt.MqttError) -> str:
    """One line saying why the broker connection failed or ended."""
    if isinstance(exc, aiomqtt.MqttCodeError) and exc.rc in _LOST:
        return "connection lost"
    text = str(exc) or type(exc).__name__
    if text == "Operation timed out":
        return "no answer from the broker (timed out)"
    return text.removesuffix(".")


class _PackedOnce(Properties):
    """Publish properties that never change, packed once (paho packs them on every
    publish: about 20 us each, three times per prediction)."""

    def pack(self) -> bytes:
        packed: bytes | None = getattr(self, "_packed", None)
        if packed is None:
            packed = super().pack()  # type: ignore[no-untyped-call]
            object.__setattr__(self, "_packed", packed)  # paho checks the names it sets
        return packed


def _properties(fmt: Literal["json", "msgpack"], expiry_s: int | None) -> Properties:
    """MQTT v5 publish properties: content type, and expiry for what goes stale."""
    props = _PackedOnce(PacketTypes.PUBLISH)  # type: ignore[no-untyped-call]
    props.ContentType = CONTENT_TYPES[fmt]
    if expiry_s is not None:
        props.MessageExpiryInterval = expiry_s
    return props


async def _wait_any(*events: asyncio.Event) -> None:
    waiters = [asyncio.ensure_future(e.wait()) for e in events]
    try:
        await asyncio.wait(waiters, return_when=asyncio.FIRST_COMPLETED)
    finally:
        for w in waiters:
            w.cancel()
