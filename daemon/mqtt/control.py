"""Remote control over MQTT: start and stop a recording, mark an event, reset the count.

Off unless ``mqtt.control`` (``--control``, ``SCOTTI_MQTT_CONTROL``). A device
with control on takes requests on ``<prefix>/<id>/cmd/<verb>``:

- ``record/start``: a session file (and, with the ``[outputs]`` extra, an MCAP
  file of the Foxglove channels) in ``mqtt.control_dir``;
- ``record/stop``: closes what is recording (also a ``--record`` file);
- ``event/mark``: an event record in both files, echoed on ``<prefix>/<id>/event``;
- ``repetitions/reset``: the repetition count starts again from 0.

Every request is answered, on the MQTT v5 response topic it names (with its
correlation data) or on ``<prefix>/<id>/reply/<verb>``: ``{"ok": true, ...}`` or
``{"ok": false, "reason": "..."}``. A malformed payload, an unknown verb or a
stop with nothing recording is such an answer and a count in
``health.pipeline.control``, never an exception out of here.

Requests come over a connection of their own (client id ``<the device's>-control``),
not the one the predictions leave by: a flood of requests or of replies never
queues in front of a pose. They are bounded so a flood cannot take the event loop
either: aiomqtt's incoming queue holds ``control_queue`` requests, more are dropped
and counted (not logged one by one); they are handled one at a time, at most
``control_rate`` a second. A flood (far more dropped than any controller sends)
makes it unsubscribe for a while, so the broker stops handing it over at all. Who
may send requests is the broker's ACL (docs/mqtt.md): the daemon never sees a
publish the broker refused.
"""

from __future__ import annotations

import asyncio
import json
import logging
import time
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any, Final

import aiomqtt
import msgpack
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties
from paho.mqtt.reasoncodes import ReasonCode
from pydantic import BaseModel, ValidationError
from scotti.daemon.mqtt.control_recording import ControlRecordings, Outcome
from scotti.daemon.mqtt.publisher import explain
from scotti.daemon.mqtt.schemas import (
    CONTENT_TYPES,
    REQUESTS,
    EventMark,
    RecordStart,
    Reply,
)
from scotti.daemon.outputs.event_mcap import mcap_missing
from scotti.daemon.settings.mqtt import MqttSettings
from scotti.daemon.waiting import Backoff, wait_event

if TYPE_CHECKING:
    from scotti.daemon.frames.pipeline import Pipeline, Prediction
    from scotti.daemon.mqtt.schemas import Status

__all__ = ["Control", "ControlStats", "mcap_missing"]  # mcap_missing: tests ask it here

log = logging.getLogger(__name__)

QOS: Final = 1  # requests, replies and events: must arrive, late is fine
MAX_REQUEST_BYTES: Final = 4096  # a request is a small JSON object
MAX_RESPONSE_TOPIC: Final = 512
MAX_VERB_SHOWN: Final = 64
BACKOFF_START_S: Final = 0.25
# A flood: more dropped requests within a second than FLOOD_DROPS_MIN or two seconds'
# worth at control_rate (40 by default), beyond what any controller sends. The daemon
# then unsubscribes from cmd/# for FLOOD_PAUSE_S, doubled while floods go on (up to
# FLOOD_PAUSE_MAX_S): even the reading and dropping of each message costs the event loop
# (docs/mqtt.md, "A flood of requests").
FLOOD_DROPS_MIN: Final = 20
FLOOD_PAUSE_S: Final = 5.0
FLOOD_PAUSE_MAX_S: Final = 60.0


@dataclass
class ControlStats:
    """``health.pipeline.control``."""

    received: int = 0  # requests taken from the queue
    ok: int = 0  # answered ok
    refused: int = 0  # answered with a reason (malformed and unknown ones included)
    malformed: int = 0  # payload not a valid request of its verb
    unknown_verb: int = 0
    dropped_queue_full: int = 0  # arrived while ``control_queue`` requests were waiting
    reply_errors: int = 0  # replies or events the broker connection lost
    subscribed: bool = False  # the broker granted the subscription to cmd/#
    connects: int = 0
    flood_pauses: int = 0  # times it stopped listening for a while (a flood)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def _bounded_queue(stats: ControlStats) -> type[asyncio.Queue[aiomqtt.Message]]:
    """aiomqtt's incoming queue, dropping what does not fit and counting it (aiomqtt's own
    bounded queue logs a WARNING per dropped message: a flood would flood the log too)."""

    class DroppingQueue(asyncio.Queue[aiomqtt.Message]):
        def put_nowait(self, item: aiomqtt.Message) -> None:
            if self.full():
                stats.dropped_queue_full += 1
                return
            super().put_nowait(item)

    return DroppingQueue


class Control:
    """One device's remote control; ``await control.run(stop)`` until ``stop``, then
    ``await control.close()`` once the pipeline no longer records. ``mcap_metadata``: the
    ``scotti`` record of the MCAP files it writes (``outputs.recording_metadata``)."""

    def __init__(
        self,
        settings: MqttSettings,
        device_id: str,
        pipeline: Pipeline,
        mcap_metadata: Mapping[str, str] | None = None,
    ) -> None:
        self.settings = settings
        self.device_id = device_id
        self.pipeline = pipeline
        self.mcap_metadata = mcap_metadata
        self.stats = ControlStats()
        self._cmd = settings.topic("cmd/")
        self._own = f"{settings.topic_prefix}/"
        self._replies = settings.topic("reply/")
        self._v5 = settings.protocol == "5"
        self._recordings = ControlRecordings(
            settings.control_dir, device_id, pipeline, mcap_metadata
        )
        self._last_seq: int | None = None
        self._next_at = 0.0  # monotonic time the next request may be handled
        self._flood_limit = max(FLOOD_DROPS_MIN, round(2 * settings.control_rate))
        self._window = (time.monotonic(), 0)  # (start, dropped by then) of the flood window
        self._pause_s = FLOOD_PAUSE_S  # doubled while floods go on
        self._calm_since = time.monotonic()
        self._state = "connecting"
        base = settings.client_id or f"scotti-daemon-{device_id}"
        self._client = aiomqtt.Client(
            settings.host,
            settings.port,
            username=settings.username,
            password=settings.password.get_secret_value() if settings.password else None,
            identifier=f"{base}-control",
            protocol=aiomqtt.ProtocolVersion.V5 if self._v5 else aiomqtt.ProtocolVersion.V311,
            keepalive=settings.keepalive_s,
            timeout=5,
            tls_context=settings.tls_context(),
            logger=logging.getLogger("scotti.daemon.mqtt.paho"),
            queue_type=_bounded_queue(self.stats),
            max_queued_incoming_messages=settings.control_queue,
        )

    # --- from the device (event loop, never blocks) ------------------------------
    def prediction(self, p: Prediction) -> None:
        self._last_seq = p.seq
        self._recordings.prediction(p)

    def status(self, status: Status) -> None:
        self._recordings.status(status)

    # --- the connection ------------------------------------------------------------
    async def run(self, stop: asyncio.Event) -> None:
        backoff = Backoff(BACKOFF_START_S, cap_s=self.settings.reconnect_max_s, jitter=0.0)
        while not stop.is_set():
            try:
                async with self._client:
                    self.stats.connects += 1
                    await self._subscribe()
                    backoff.reset()
                    await _until(stop, self._take_requests())
                return
            except aiomqtt.MqttError as exc:
                self._lost(explain(exc))
            await wait_event(stop, backoff.next_delay())

    async def _subscribe(self) -> None:
        topic = self._cmd + "#"
        granted = await self._client.subscribe(topic, qos=QOS)
        code = granted[0] if granted else 0x80  # v5: a ReasonCode; 3.1.1: the granted QoS
        value = code.value if isinstance(code, ReasonCode) else int(code)
        self.stats.subscribed = value < 0x80
        if not self.stats.subscribed:
            log.warning(
                "remote control: the broker refused the subscription to %s (%s): "
                "no requests will arrive (the broker's ACL, docs/mqtt.md)",
                topic,
                code,
            )
        elif self._state != "connected":
            log.info("remote control: taking requests on %s", topic)
        self._state = "connected"

    def _lost(self, reason: str) -> None:
        self.stats.subscribed = False
        if self._state != "disconnected":
            log.warning("remote control: broker %s: %s; retrying", self.settings.broker, reason)
        self._state = "disconnected"

    async def _take_requests(self) -> None:
        async for message in self._client.messages:
            if self._flooded():
                self.stats.dropped_queue_full += 1  # a request of the flood, unanswered
                await self._pause()
                continue
            await self._pace()
            await self._answer(message)

    def _flooded(self) -> bool:
        now, dropped = time.monotonic(), self.stats.dropped_queue_full
        start, dropped_then = self._window
        if dropped - dropped_then >= self._flood_limit:
            self._window = (now, dropped)
            return True
        if now - start >= 1.0:
            self._window = (now, dropped)
        return False

    async def _pause(self) -> None:
        """Stop listening for a while: the broker no longer hands the flood over at all."""
        now = time.monotonic()
        if now - self._calm_since > FLOOD_PAUSE_MAX_S:
            self._pause_s = FLOOD_PAUSE_S  # the first flood for a while
        topic = self._cmd + "#"
        await self._client.unsubscribe(topic)
        self.stats.subscribed = False
        self.stats.flood_pauses += 1
        log.warning(
            "remote control: flooded (%d requests dropped within a second); not taking "
            "requests for %.0f s",
            self._flood_limit,
            self._pause_s,
        )
        await asyncio.sleep(self._pause_s)
        self._pause_s = min(FLOOD_PAUSE_MAX_S, 2 * self._pause_s)
        await self._subscribe()
        self._calm_since = time.monotonic()
        self._window = (self._calm_since, self.stats.dropped_queue_full)
        log.info("remote control: taking requests on %s again", topic)

    async def _pace(self) -> None:
        """At most ``control_rate`` requests a second, so a flood waits (and overflows
        the queue, counted) instead of taking the event loop."""
        now = time.monotonic()
        if self._next_at > now:
            await asyncio.sleep(self._next_at - now)
        self._next_at = max(now, self._next_at) + 1.0 / self.settings.control_rate

    # --- one request -----------------------------------------------------------------
    async def _answer(self, message: aiomqtt.Message) -> None:
        self.stats.received += 1
        verb = message.topic.value.removeprefix(self._cmd)
        props = message.properties
        response_topic = getattr(props, "ResponseTopic", None)
        correlation = getattr(props, "CorrelationData", None)
        content_type = getattr(props, "ContentType", None)
        topic = self._replies + (verb if verb in REQUESTS else "unknown")
        refusal = None if response_topic is None else self._bad_response_topic(response_topic)
        if response_topic is not None and refusal is None:
            topic = response_topic
        try:
            if refusal is not None:
                reply = self._fail(verb, refusal)
            else:
                reply = await self._do(verb, message.payload, content_type)
        except aiomqtt.MqttError:
            raise  # the connection is gone: the reply could not go out either
        except Exception as exc:  # a bug here must not end remote control, nor the daemon
            log.exception("remote control: %s failed", verb[:MAX_VERB_SHOWN])
            reply = self._fail(verb, f"internal error: {type(exc).__name__}: {exc}")
        await self._send(topic, reply, correlation)

    def _bad_response_topic(self, topic: str) -> str | None:
        """Why the daemon will not answer on ``topic``, or None. Under the topic prefix only
        ``<prefix>/<id>/reply/...``: a reply must never pass for a status, a pose or another
        request (into ``cmd/`` it would come back as one)."""
        if not topic or len(topic) > MAX_RESPONSE_TOPIC:
            return f"response topic must be 1..{MAX_RESPONSE_TOPIC} characters"
        if any(c in topic for c in "+#\0") or topic.startswith("$"):
            return "response topic must not hold + # or NUL, nor start with $"
        if topic.startswith(self._own) and not topic.startswith(self._replies):
            return f"response topic under {self._own} must be under {self._replies}"
        return None

    async def _do(self, verb: str, payload: Any, content_type: str | None) -> Reply:
        model = REQUESTS.get(verb)
        if model is None:
            self.stats.unknown_verb += 1
            known = ", ".join(REQUESTS)
            return self._fail(verb, f"unknown verb {verb[:MAX_VERB_SHOWN]!r}; known: {known}")
        try:
            request = _parse(model, payload, content_type)
        except ValueError as exc:
            self.stats.malformed += 1
            return self._fail(verb, f"malformed request: {exc}")
        if isinstance(request, RecordStart):
            return await self._record_start(request)
        if isinstance(request, EventMark):
            return await self._event_mark(request)
        if verb == "record/stop":
            return await self._record_stop()
        assert verb == "repetitions/reset", verb
        self.pipeline.repetitions.reset()
        log.info("remote control: repetition count reset")
        return self._ok(verb)

    async def _record_start(self, request: RecordStart) -> Reply:
        return self._reply("record/start", await self._recordings.start(request))

    async def _record_stop(self) -> Reply:
        outcome = await self._recordings.stop()
        if not isinstance(outcome, str):
            log.info("remote control: recording to %s stopped", outcome["session"])
        return self._reply("record/stop", outcome)

    async def _event_mark(self, request: EventMark) -> Reply:
        # One seq for the files, the echo and the reply: predictions go on arriving
        # while the echo is being sent, and the reply must name the frame the mark was put at.
        event, fields = self._recordings.mark(request, self._last_seq)
        await self._send(self.settings.topic("event"), event, None)
        return self._ok("event/mark", **fields)

    # --- answers -----------------------------------------------------------------------
    def _ok(self, verb: str, **fields: Any) -> Reply:
        self.stats.ok += 1
        fields.setdefault("seq", self._last_seq)
        return Reply(ok=True, verb=verb, host_wall_ns=time.time_ns(), **fields)

    def _reply(self, verb: str, outcome: Outcome) -> Reply:
        return self._fail(verb, outcome) if isinstance(outcome, str) else self._ok(verb, **outcome)

    def _fail(self, verb: str, reason: str) -> Reply:
        self.stats.refused += 1
        return Reply(
            ok=False,
            verb=verb[:MAX_VERB_SHOWN],
            reason=reason,
            host_wall_ns=time.time_ns(),
            seq=self._last_seq,
        )

    async def _send(self, topic: str, payload: BaseModel, correlation: bytes | None) -> None:
        props: Properties | None = None
        if self._v5:
            props = Properties(PacketTypes.PUBLISH)  # type: ignore[no-untyped-call]
            props.ContentType = CONTENT_TYPES[self.settings.format]
            if correlation is not None:
                props.CorrelationData = correlation
        data = payload.model_dump(mode="json", exclude_none=True)
        body = (
            json.dumps(data, separators=(",", ":")).encode()
            if self.settings.format == "json"
            else msgpack.packb(data, use_bin_type=True)
        )
        try:
            await self._client.publish(topic, body, qos=QOS, retain=False, properties=props)
        except aiomqtt.MqttError:
            self.stats.reply_errors += 1
            raise

    # --- the end -----------------------------------------------------------------------
    async def close(self) -> None:
        """Close what ``record/start`` opened (the files' last bytes, the MCAP index)."""
        await self._recordings.close()


def _parse(model: type[BaseModel], payload: Any, content_type: str | None) -> BaseModel:
    """The request in ``payload`` (JSON, or msgpack by its content type); ValueError in one
    line naming the field."""
    raw = payload if isinstance(payload, bytes | bytearray) else str(payload or "").encode()
    if len(raw) > MAX_REQUEST_BYTES:
        msg = f"{len(raw)} bytes; at most {MAX_REQUEST_BYTES}"
        raise ValueError(msg)
    try:
        if content_type == CONTENT_TYPES["msgpack"]:
            data = msgpack.unpackb(raw, raw=False) if raw else {}
        else:
            data = json.loads(raw) if raw.strip() else {}
    except (ValueError, msgpack.UnpackException) as exc:
        msg = f"not {'msgpack' if content_type == CONTENT_TYPES['msgpack'] else 'JSON'}: {exc}"
        raise ValueError(msg) from None
    if not isinstance(data, dict):
        msg = f"a JSON object is wanted, not {type(data).__name__}"
        raise ValueError(msg)
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        first = exc.errors(include_url=False)[0]
        where = ".".join(str(p) for p in first["loc"]) or "request"
        raise ValueError(f"{where}: {first['msg']}") from None


async def _until(stop: asyncio.Event, work: Any) -> None:
    """Run ``work`` until it ends (its error raised) or ``stop`` is set (it is cancelled)."""
    task = asyncio.ensure_future(work)
    stopper = asyncio.ensure_future(stop.wait())
    try:
        await asyncio.wait({task, stopper}, return_when=asyncio.FIRST_COMPLETED)
    finally:
        for t in (task, stopper):
            t.cancel()
        await asyncio.gather(task, stopper, return_exceptions=True)
    if not task.cancelled() and (exc := task.exception()) is not None:
        raise exc
