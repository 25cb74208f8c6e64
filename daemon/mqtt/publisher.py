"""MQTT publishing: one connection at a time (``connection.Connection``), in a reconnect loop.

The pipeline hands over each ``Prediction`` as it is, through a bounded
queue that drops the oldest (the reader never waits for the broker); its
messages are encoded here, as it is published: plain dicts
(``messages.frame_dicts``) through pydantic's serialiser, no model instance
per message. The loop here connects (also when the broker is down at boot:
it keeps retrying with backoff), republishes the retained ``status`` and
``info`` on every connect, then publishes predictions as they come: each
wake-up takes every queued prediction (up to the next status change) and
hands all their messages to the socket in one write, waiting only when the
socket is full. Each status change is published in order, and never before
the predictions submitted ahead of it (a consumer that reads "receiver
disconnected" gets no older pose after it); after a reconnect only the
current status goes out. Health is "latest wins" and may overtake
predictions.

A broker that goes away, restarts or refuses is said in the log as
``broker_outage`` says; a status only once the broker has acknowledged it
(``on_status_published``). A broker that does not acknowledge a QoS 1
publish, or take the bytes of QoS 0 ones, within ``ack_timeout_s`` is treated
as gone (``acknowledged``); health counts it (``publish.broker_not_acknowledging``)
with the messages in flight (``publish.unacknowledged``). Our own retained
status is watched and another client's replaced (``status_watch``). Under
MQTT v5 a QoS 1 publish the broker refuses (PUBACK reason code >= 0x80, e.g.
an ACL) is counted and reported in health (``publish.refused``), not counted
as published; per-frame messages go at QoS 0, which has no acknowledgement to
refuse them with.

Pattern: aiomqtt docs/reconnection.md (one reconnect loop around the client;
here a fresh paho client per connection, see ``connection``).
"""

from __future__ import annotations

import asyncio
import collections
import logging
import time
from collections.abc import Awaitable, Callable
from typing import TYPE_CHECKING, Final, Literal, TypeVar

from paho.mqtt.properties import Properties
from paho.mqtt.reasoncodes import ReasonCode
from pydantic import BaseModel
from scotti.daemon.mqtt import messages, packets
from scotti.daemon.mqtt.acknowledged import NotAcknowledgingError, acknowledged
from scotti.daemon.mqtt.broker_outage import Outage
from scotti.daemon.mqtt.broker_outage import explain as explain  # control.py's import
from scotti.daemon.mqtt.connection import BrokerLostError, Connection
from scotti.daemon.mqtt.latency_slot import LatencySlot, value_bytes
from scotti.daemon.mqtt.publisher_stats import PublisherStats
from scotti.daemon.mqtt.schemas import Health, Info, Status, encode, encode_dict
from scotti.daemon.mqtt.status_watch import StatusWatch
from scotti.daemon.settings.mqtt import MqttSettings
from scotti.daemon.waiting import Backoff, wait_event

if TYPE_CHECKING:
    from scotti.daemon.frames.pipeline import Prediction

log = logging.getLogger(__name__)
MQTT_LOGGER: Final = "scotti.daemon.mqtt.paho"  # paho logs here (service/main.py, loop_errors.py)
T = TypeVar("T")

BACKOFF_START_S: Final = 0.25
RETAINED_QOS: Final = 1  # status/info/health: must arrive, late is fine
MAX_PENDING_STATUSES: Final = 16  # status changes kept while the broker is slow or away
FRAME_TOPICS: Final = ("pose", "action", "progress", "pressure")  # QoS 0: a newer one is 62 ms away
DROP_LOG_EVERY_S: Final = 10.0  # a full queue is logged at most this often (and counted)
SAY_EVERY_S: Final = 10.0  # a refusal or a replaced status is logged at most this often


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
        self._outage = Outage(settings)
        self._source_waiting = False  # a replay is held in ``wait_room`` now
        self._said_source_waits = False  # ... and the log said so in this outage
        self._fmt = settings.format
        self._info = info
        self._status: Status | None = None
        self._health: Health | None = None
        # Status changes not yet published: (predictions submitted before it, status), in order.
        self._statuses: collections.deque[tuple[int, Status]] = collections.deque(
            maxlen=MAX_PENDING_STATUSES
        )
        self._health_dirty = False
        self._queue: collections.deque[Prediction] = collections.deque()
        self._pressure_downsample = settings.pressure_downsample if settings.pressure else 0
        self._submitted = 0  # predictions ever submitted
        self._drop_logged_at = -DROP_LOG_EVERY_S  # the first drop is logged at once
        self._wake = asyncio.Event()  # a prediction, a status, health, a restore, or stop
        self._room = asyncio.Event()  # set whenever a prediction leaves the queue
        v5 = settings.protocol == "5"  # MQTT 3.1.1 has no properties: none are sent
        fmt = self._fmt
        frame_props = packets.publish_properties(fmt, settings.message_expiry_s) if v5 else None
        self._retained_props = packets.publish_properties(fmt, None) if v5 else None
        health_expiry = max(1, round(3 * settings.health_interval_s))
        self._health_props = packets.publish_properties(fmt, health_expiry) if v5 else None
        # Each frame topic's PUBLISH header, built once (``packets``).
        self._frame_headers = {
            name: packets.topic_header(settings.topic(name), frame_props) for name in FRAME_TOPICS
        }
        self._will = (settings.topic("status"), encode(will, fmt), self._retained_props)
        self._conn: Connection | None = None  # the current connection, while there is one
        self._tls = settings.tls_context()  # the files read once, at start
        self._said_at: dict[str, float] = {}  # what was logged when, for once-per-burst lines
        self._status_watch = StatusWatch(settings, self._wake.set, self._say)

    # --- called from the pipeline's side (event loop thread, never blocks) ---
    @property
    def queue_depth(self) -> int:
        return len(self._queue)

    def submit(self, prediction: Prediction) -> None:
        """Queue one prediction's messages; encoded only when published (a prediction
        dropped from the queue costs no encoding)."""
        if len(self._queue) >= self.settings.queue_size:
            self._queue.popleft()
            self.stats.dropped_full += 1
            self._log_drop()
        self._queue.append(prediction)
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
            "the broker is unreachable or not acknowledging"
            if self.state != "connected"
            else "the broker or this host is slower than the insoles"
        )
        log.warning(
            "publish queue full (%d): dropped the oldest prediction (%d so far); %s",
            self.settings.queue_size,
            self.stats.dropped_full,
            why,
        )

    async def wait_room(self, margin: int) -> None:
        """Wait until the queue has room for ``margin`` more predictions (a replay waits
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
        stop_seen = asyncio.create_task(self._wake_on(stop), name="publisher-stop")
        try:
            await self._connect_loop(stop)
        finally:
            stop_seen.cancel()

    async def _wake_on(self, stop: asyncio.Event) -> None:
        """The pump waits on one event; ``stop`` sets it too."""
        await stop.wait()
        self._wake.set()

    async def _connect_loop(self, stop: asyncio.Event) -> None:
        backoff = Backoff(BACKOFF_START_S, cap_s=self.settings.reconnect_max_s, jitter=0.0)
        while True:
            conn = Connection(
                self.settings,
                self._will,
                self._status_watch.seen,
                logging.getLogger(MQTT_LOGGER),
                self._tls,
            )
            self._conn = conn
            try:
                await conn.open()
                # "connected" once the broker has taken a message, not at CONNACK: a
                # connection that stalls at once stays part of the same outage (one
                # WARNING), and the backoff starts afresh only after a working one.
                await self._publish(self.settings.topic("info"), self._info)
                self.stats.connects += 1
                backoff.reset()
                self._set_state("connected", self.settings.broker)
                self._health_dirty = True
                if self._status is not None:  # the current one, still after older frames
                    mark = self._statuses[-1][0] if self._statuses else 0
                    self._statuses = collections.deque(
                        [(mark, self._status)], maxlen=MAX_PENDING_STATUSES
                    )
                await self._flush_retained()
                await self._status_watch.watch(conn, self._wait)
                await self._pump(stop)
                await conn.close()
                self._set_state("stopped", "")
                return
            except BrokerLostError as exc:
                self._set_state("disconnected", str(exc))
            finally:
                conn.abort()
                self._conn = None
            if stop.is_set():
                self._set_state("stopped", "")
                return
            await wait_event(stop, backoff.next_delay())

    async def _pump(self, stop: asyncio.Event) -> None:
        while True:
            self._wake.clear()
            await self._flush_retained()
            while self._queue:
                await self._publish_predictions(self._next_batch())
                await self._flush_retained()  # status changes overtake a long backlog
            if stop.is_set():
                self.on_drained()  # the last health and status, after the last frame
                await self._flush_retained()
                return
            await self._wake.wait()

    def _next_batch(self) -> int:
        """How many queued predictions go out together: all of them, up to the next
        status change (which is published after exactly the predictions before it)."""
        count = len(self._queue)
        if self._statuses:
            taken = self._submitted - count
            count = min(count, max(1, self._statuses[0][0] - taken))
        return count

    async def _flush_retained(self) -> None:
        taken = self._submitted - len(self._queue)  # predictions published or dropped
        while self._statuses and self._statuses[0][0] <= taken:
            status = self._statuses[0][1]
            if await self._publish(self.settings.topic("status"), status):
                self.on_status_published(status)
            self._statuses.popleft()
            self._status_watch.taken()
        if self._status_watch.restore_due:
            await self._restore_status()
        if self._health_dirty and self._health is not None:
            self._health_dirty = False
            await self._publish(self.settings.topic("health"), self._health, self._health_props)

    def encode_frame(self, prediction: Prediction) -> list[tuple[bytes, LatencySlot]]:
        """(PUBLISH header of its topic, payload) of each of one prediction's messages:
        pose, action, progress, and pressure when it is on; latency_ms left open,
        written in as the bytes leave."""
        fmt = self._fmt
        headers = self._frame_headers
        return [
            (headers[name], LatencySlot.cut(encode_dict(data, fmt), fmt))
            for name, data in messages.frame_dicts(prediction, 0.0, self._pressure_downsample)
        ]

    async def _publish_predictions(self, count: int) -> None:
        """Take ``count`` predictions from the queue and publish them with one write to the
        socket (``Connection.write``); wait only when the socket is full."""
        conn = self._connection
        expiry_ns = self.settings.message_expiry_s * 1e9
        origins: list[tuple[int, int]] = []  # (seq, its origin) of each one queued
        for _ in range(count):
            prediction = self._queue.popleft()
            if self.drop_stale and time.monotonic_ns() - prediction.host_mono_ns > expiry_ns:
                self.stats.dropped_stale += 1
                continue
            # The last byte of the newest frame; 0 when unknown: latency is then measured
            # from inference.
            origin = prediction.last_byte_mono_ns or prediction.host_mono_ns
            # Each payload is encoded once, its latency_ms left open and written in just
            # before the bytes are queued for the socket (``LatencySlot``): the payload's
            # age when it leaves, encoding included. A prediction's messages leave in
            # the same send, so they carry the same value.
            encoded = self.encode_frame(prediction)
            latency = value_bytes((time.monotonic_ns() - origin) / 1e6, self._fmt)
            for header, slot in encoded:
                conn.queue_frame(packets.packet(header, slot.filled(latency)))
            origins.append((prediction.seq, origin))
        self._room.set()
        if not origins:
            return
        conn.write()
        try:
            if conn.lost.done():  # the write found the connection gone
                raise BrokerLostError(conn.lost.result())
            if conn.frames_waiting:  # the socket is full: wait until it takes them
                await self._wait(conn.frames_written())
        except BrokerLostError:
            self.stats.dropped_error += len(origins)
            raise
        # health's end_to_end: up to the write to the socket.
        now = time.monotonic_ns()
        stats = self.stats
        stats.published += len(origins)
        stats.last_seq = origins[-1][0]
        for _seq, origin in origins:
            stats.latency_ms.add((now - origin) / 1e6)

    async def _publish(
        self, topic: str, payload: BaseModel, props: Properties | None = None
    ) -> bool:
        """One retained message at QoS 1, acknowledged; False when the broker refused it."""
        return await self._publish_data(topic, encode(payload, self._fmt), props)

    async def _publish_data(self, topic: str, data: bytes, props: Properties | None = None) -> bool:
        props = props if props is not None else self._retained_props
        conn = self._connection
        reason = await self._wait(conn.publish(topic, data, RETAINED_QOS, True, props))
        if reason is not None and reason.is_failure:
            self._refused(topic, reason)
            return False
        if topic == self._status_watch.topic:
            self._status_watch.published(data, conn.v5)
        return True

    @property
    def _connection(self) -> Connection:
        if self._conn is None:
            msg = "not connected"
            raise BrokerLostError(msg)
        return self._conn

    async def _wait(self, publish: Awaitable[T]) -> T:
        """Await a publish (or a subscribe); ``BrokerLostError`` as soon as the connection
        ends, or when the broker has not acknowledged it within ``ack_timeout_s``."""
        try:
            return await acknowledged(self._connection, publish, self.settings.ack_timeout_s)
        except NotAcknowledgingError:
            self.stats.not_acknowledging += 1
            raise

    @property
    def unacknowledged(self) -> int:
        """QoS 1 messages handed to the broker and not yet acknowledged, now."""
        return self._conn.unacknowledged if self._conn is not None else 0

    def _refused(self, topic: str, reason: ReasonCode) -> None:
        self.stats.refused += 1
        self.stats.last_refused = f"{topic}: {reason} (0x{reason.value:02x})"
        self._say(
            "refused",
            "broker %s refused a publish on %s: %s (0x%02x, %d refused so far); check its ACL",
            self.settings.broker,
            topic,
            reason,
            reason.value,
            self.stats.refused,
        )

    async def _restore_status(self) -> None:
        """Publish our status again over another client's (``StatusWatch`` says when)."""
        truth = self._status_watch.take_restore()
        if truth is None:
            return
        self.stats.status_restored += 1
        self._say(
            "restored",
            "status on %s was changed by another client (same device id twice, or forged); "
            "published ours again (%d times so far)",
            self._status_watch.topic,
            self.stats.status_restored,
        )
        await self._publish_data(self._status_watch.topic, truth)

    def _say(self, what: str, fmt: str, *args: object) -> None:
        """A WARNING, at most once every SAY_EVERY_S for the same ``what``; debug between."""
        now = time.monotonic()
        if now - self._said_at.get(what, -SAY_EVERY_S) >= SAY_EVERY_S:
            self._said_at[what] = now
            log.warning(fmt, *args)
        else:
            log.debug(fmt, *args)

    def _set_state(self, state: BrokerState, detail: str) -> None:
        if state == "disconnected":
            self.stats.last_error = detail
            if self._outage.failed(detail):
                self.stats.outages += 1
        else:  # the outage, if one, is over
            self.stats.unreachable_s += self._outage.end()
        if state == self.state:
            return
        self.state = state
        if state == "connected":
            log.info("broker %s: connected", self.settings.broker)
            self._said_source_waits = False
        self.on_state_change(state, detail)
        if state == "disconnected" and self._source_waiting:
            self._say_source_waits()

    @property
    def unreachable_s(self) -> float:
        """Seconds without the broker so far, the current outage included."""
        return self.stats.unreachable_s + self._outage.current_s
