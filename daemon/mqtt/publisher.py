"""MQTT publishing: one connection at a time (``connection.Connection``), in a reconnect loop.

The pipeline hands over each ``Prediction`` as it is, through a bounded
queue that drops the oldest (the reader never waits for the broker); its
messages are encoded here, as it is published. The loop here connects (also
when the broker is down at boot: it keeps retrying with backoff),
republishes the retained ``status`` and ``info`` on every connect, then
publishes predictions as they come. Each status change is published in
order, and never before the predictions submitted ahead of it (a consumer
that reads "receiver disconnected" gets no older pose after it); after a
reconnect only the current status goes out. Health is "latest wins" and may
overtake predictions.

A broker that goes away, restarts or refuses (bad password, unknown CA) is
one WARNING line with the reason, then retries with backoff until it is back
(one INFO line), said again every ``outage_warning_s`` (15 s) while it stays
away; never an ERROR, never a traceback. A status is said in the log only
once the broker has acknowledged it (``on_status_published``).

A broker that takes the connection but does not acknowledge a QoS 1 publish
(or take a QoS 0 one) within ``ack_timeout_s`` is treated as gone: the
connection is dropped (its last will says offline) and made again with
backoff; health counts it (``publish.broker_not_acknowledging``) with the
messages in flight (``publish.unacknowledged``). Waiting costs nothing: the
publisher sleeps until an acknowledgement, a loss or the timeout.

The daemon watches its own retained ``status``: a different one published by
another client is replaced with the truth (at most once a second, counted,
logged once per burst). Under MQTT v5 a QoS 1 publish the broker refuses
(PUBACK reason code >= 0x80, e.g. an ACL) is counted and reported in health
(``publish.refused``), not counted as published; per-frame messages go at
QoS 0, which has no acknowledgement to refuse them with.

Pattern: aiomqtt docs/reconnection.md (one reconnect loop around the client;
here a fresh paho client per connection, see ``connection``).
"""

from __future__ import annotations

import asyncio
import collections
import logging
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Final, Literal, TypeVar

import aiomqtt
import paho.mqtt.client as paho
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties
from paho.mqtt.reasoncodes import ReasonCode
from pydantic import BaseModel
from scotti.daemon.mqtt import messages
from scotti.daemon.mqtt.connection import BrokerLostError, Connection
from scotti.daemon.mqtt.latency_slot import LatencySlot
from scotti.daemon.mqtt.schemas import CONTENT_TYPES, Health, Info, Status, encode
from scotti.daemon.service.counters import LatencyRing
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
FRAME_QOS: Final = 0  # pose/action/progress: a newer one is 62 ms away
DROP_LOG_EVERY_S: Final = 10.0  # a full queue is logged at most this often (and counted)
RESTORE_EVERY_S: Final = 1.0  # a status of another client's is replaced at most this often
SAY_EVERY_S: Final = 10.0  # a refusal or a replaced status is logged at most this often


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
    not_acknowledging: int = 0  # connections dropped: a publish unanswered too long
    refused: int = 0  # QoS 1 publishes the broker refused (PUBACK reason code >= 0x80)
    last_refused: str = ""  # the topic and reason of the latest refusal
    status_restored: int = 0  # times another client's status on our topic was replaced

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
        # Status changes not yet published: (predictions submitted before it, status), in order.
        self._statuses: collections.deque[tuple[int, Status]] = collections.deque(
            maxlen=MAX_PENDING_STATUSES
        )
        self._health_dirty = False
        self._queue: collections.deque[Prediction] = collections.deque()
        self._pressure_downsample = settings.pressure_downsample if settings.pressure else 0
        self._submitted = 0  # predictions ever submitted
        self._drop_logged_at = -DROP_LOG_EVERY_S  # the first drop is logged at once
        self._wake = asyncio.Event()
        self._room = asyncio.Event()  # set whenever a prediction leaves the queue
        v5 = settings.protocol == "5"  # MQTT 3.1.1 has no properties: none are sent
        self._frame_props = _properties(self._fmt, settings.message_expiry_s) if v5 else None
        self._retained_props = _properties(self._fmt, None) if v5 else None
        health_expiry = max(1, round(3 * settings.health_interval_s))
        self._health_props = _properties(self._fmt, health_expiry) if v5 else None
        self._will = (settings.topic("status"), encode(will, self._fmt), self._retained_props)
        self._conn: Connection | None = None  # the current connection, while there is one
        self._tls = settings.tls_context()  # the files read once, at start
        self._status_sent: bytes | None = None  # the status the broker last acknowledged
        self._echoes: collections.deque[bytes] = collections.deque(maxlen=MAX_PENDING_STATUSES)
        self._restore = False  # another client's status seen: publish ours again
        self._status_watched = False  # our status topic delivers to us (this connection)
        self._restored_at = -RESTORE_EVERY_S
        self._said_at: dict[str, float] = {}  # what was logged when, for once-per-burst lines

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
        backoff = Backoff(BACKOFF_START_S, cap_s=self.settings.reconnect_max_s, jitter=0.0)
        while True:
            conn = Connection(
                self.settings,
                self._will,
                self._status_seen,
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
                # Watched from now on: what the broker holds is what was just published,
                # so anything different that comes is another client's.
                self._echoes.clear()
                await self._watch_status(conn)
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
                prediction = self._queue.popleft()
                self._room.set()
                await self._publish_prediction(prediction)
                await self._flush_retained()  # status changes overtake a long backlog
            if stop.is_set():
                self.on_drained()  # the last health and status, after the last frame
                await self._flush_retained()
                return
            await _wait_any(self._wake, stop)

    async def _flush_retained(self) -> None:
        taken = self._submitted - len(self._queue)  # predictions published or dropped
        while self._statuses and self._statuses[0][0] <= taken:
            status = self._statuses[0][1]
            if await self._publish(self.settings.topic("status"), status):
                self.on_status_published(status)
            self._statuses.popleft()
            self._restore = False  # what the broker holds now is ours
        if self._restore:
            await self._restore_status()
        if self._health_dirty and self._health is not None:
            self._health_dirty = False
            await self._publish(self.settings.topic("health"), self._health, self._health_props)

    def frame_messages(self, prediction: Prediction) -> list[tuple[str, BaseModel]]:
        """(topic name, payload) of one prediction: pose, action, progress, and pressure
        when it is on; latency_ms left at 0, written in as the bytes leave."""
        return messages.frame_payloads(prediction, 0.0, self._pressure_downsample)

    async def _publish_prediction(self, prediction: Prediction) -> None:
        now = time.monotonic_ns()
        made = prediction.host_mono_ns
        if self.drop_stale and now - made > self.settings.message_expiry_s * 1e9:
            self.stats.dropped_stale += 1
            return
        # The last byte of the newest frame; 0 when unknown: latency is then measured
        # from inference.
        origin = prediction.last_byte_mono_ns or made
        # Each payload is encoded once, its latency_ms left open and written in just
        # before the bytes go to paho (``LatencySlot``): the payload's age when it
        # leaves, encoding included. All of a prediction's messages are handed over
        # at once and the last one's write awaited: paho writes its queue in order,
        # and one await per prediction, not one per message, keeps the event loop's
        # share small at 16 pairs.
        encoded = [
            (self.settings.topic(name), LatencySlot.encode(payload, self._fmt))
            for name, payload in self.frame_messages(prediction)
        ]
        try:
            written = None
            for topic, slot in encoded:
                latency_ms = (time.monotonic_ns() - origin) / 1e6
                written = self._connection.publish(
                    topic, slot.fill(latency_ms), FRAME_QOS, False, self._frame_props
                )
            if written is not None:
                await self._wait(written)
        except BrokerLostError:
            self.stats.dropped_error += 1
            raise
        self.stats.published += 1
        self.stats.last_seq = prediction.seq
        # health's end_to_end: up to the write to the socket.
        self.stats.latency_ms.add((time.monotonic_ns() - origin) / 1e6)

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
        if topic == self.settings.topic("status"):
            self._status_sent = data
            if not conn.v5:  # 3.1.1 has no "no local": our own publish comes back
                self._echoes.append(data)
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
        conn = self._connection
        task = asyncio.ensure_future(publish)
        waiting: set[asyncio.Future[Any]] = {task, conn.lost}
        done, _ = await asyncio.wait(
            waiting,
            timeout=self.settings.ack_timeout_s,
            return_when=asyncio.FIRST_COMPLETED,
        )
        if task in done and not task.cancelled():  # cancelled: the connection ended
            return task.result()
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        if conn.lost.done():
            raise BrokerLostError(conn.lost.result())
        self.stats.not_acknowledging += 1
        msg = (
            f"not acknowledging: no answer to a publish within "
            f"{self.settings.ack_timeout_s:g} s ({conn.unacknowledged} unacknowledged)"
        )
        raise BrokerLostError(msg)

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

    # --- our own retained status, watched -------------------------------------------------
    async def _watch_status(self, conn: Connection) -> None:
        """Subscribe to our own status. The broker then hands back the retained one just
        published: if it does not (mosquitto grants the subscription and filters what
        its ACL does not let us read), the watch is blind and the log says so."""
        topic = self.settings.topic("status")
        self._status_watched = False
        code = await self._wait(conn.subscribe(topic))
        if code.is_failure:
            self._say_unwatched(str(code))
        elif self._status_sent is not None:

            def check() -> None:
                if not self._status_watched and self._conn is conn and not conn.lost.done():
                    self._say_unwatched("the retained status did not come back")

            asyncio.get_running_loop().call_later(self.settings.ack_timeout_s, check)

    def _say_unwatched(self, why: str) -> None:
        self._say(
            "unwatched",
            "cannot read %s on broker %s (%s): a status another client publishes there is "
            "not replaced; let the daemon read its own status topic (its ACL)",
            self.settings.topic("status"),
            self.settings.broker,
            why,
        )

    def _status_seen(self, message: paho.MQTTMessage) -> None:
        """A message on our status topic (paho's callback, in the loop's thread)."""
        self._status_watched = True
        payload = bytes(message.payload)
        if self._echoes and payload == self._echoes[0]:
            self._echoes.popleft()  # our own, back from the broker (MQTT 3.1.1)
            return
        if self._status_sent is None or payload == self._status_sent:
            return
        self._restore = True
        self._wake.set()

    async def _restore_status(self) -> None:
        """Publish our status again over another client's (at most once a second)."""
        wait_s = self._restored_at + RESTORE_EVERY_S - time.monotonic()
        if wait_s > 0:
            asyncio.get_running_loop().call_later(wait_s, self._wake.set)
            return
        truth = self._status_sent
        if truth is None:
            return
        self._restore = False
        self._restored_at = time.monotonic()
        self.stats.status_restored += 1
        self._say(
            "restored",
            "status on %s was changed by another client (same device id twice, or forged); "
            "published ours again (%d times so far)",
            self.settings.topic("status"),
            self.stats.status_restored,
        )
        await self._publish_data(self.settings.topic("status"), truth)

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
