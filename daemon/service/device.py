"""One insole pair in the daemon: its source, recording, pipeline, MQTT client, status
and health, all its own.

A device shares only two things with the others: the model (its frames go
through the daemon's one inference engine, batched with theirs) and the
event loop. Everything that can fail (its receiver unplugged, garbage on its
line, a foot silent, its replay ending) fails here, is reported on its own
``scotti/<id>/status``, and never holds up another device: the engine takes
whatever frames are ready, and each device publishes through its own client,
so each has its own last will (``offline``) and its own retained ``info``.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import AsyncGenerator, Callable
from typing import Any, Literal

from scotti.daemon.frames.pipeline import Pipeline, PipelineState, Prediction
from scotti.daemon.inference.engine import InferenceEngine
from scotti.daemon.input.recording import Recorder
from scotti.daemon.input.sources import Source, SourceItem
from scotti.daemon.mqtt import messages
from scotti.daemon.mqtt.control import Control
from scotti.daemon.mqtt.publisher import BrokerState, Publisher
from scotti.daemon.mqtt.schemas import Info, Status
from scotti.daemon.outputs import DeviceOutputs, recording_metadata
from scotti.daemon.service.counters import Counters
from scotti.daemon.settings import Settings
from scotti.daemon.settings.source import DeviceSettings
from scotti.daemon.waiting import wait_event
from scotti.models.kv_streaming import StepModel

log = logging.getLogger(__name__)


class Device:
    """One pair's service; ``await device.run(stop)`` until its source ends or ``stop``."""

    def __init__(
        self,
        settings: Settings,
        device: DeviceSettings,
        runtime: StepModel,
        engine: InferenceEngine,
        source: Source,
        recorder: Recorder | None,
    ) -> None:
        self.id = device.id
        self.settings = settings
        self.device = device
        self.mqtt = settings.mqtt_for(device)
        self.runtime = runtime
        self.engine = engine
        self.source = source
        self.recorder = recorder
        self.counters = Counters()
        self.started_mono = time.monotonic()
        self.outputs = DeviceOutputs(None, self.id)  # MCAP, Foxglove, LSL, web: app.py sets
        self.publisher: Publisher | None = None
        self.control: Control | None = None  # remote control, with mqtt.control on
        self.state: PipelineState | None = None
        self.on_change: Callable[[Device], None] = lambda _d: None  # state or broker changed
        self._status_key: tuple[object, ...] | None = None
        self._logged_status: tuple[object, ...] | None = None  # the last one the log said

    async def run(self, stop: asyncio.Event, info: Info) -> int:
        """0 when the source ended or ``stop`` was set and the stop was clean, else 1."""
        settings = self.settings
        publisher = Publisher(
            self.mqtt,
            info=info,
            will=messages.status("offline", ["connection lost (last will)"], None),
        )
        self.publisher = publisher
        publisher.on_state_change = self._on_broker_state
        publisher.on_status_published = self._on_status_published
        publisher.set_status(messages.status("degraded", ["starting"], None))
        source = self.source
        publisher.drop_stale = source.live
        if not source.live:  # a replay waits for the broker rather than lose predictions
            # Room for the engine's backlog of this device too, and a frame or two more.
            source = _PacedByPublisher(source, publisher, settings.inference.queue_size + 2)
        pipeline = Pipeline(
            source,
            self.runtime,
            self.counters,
            self.recorder,
            max_queue=settings.inference.queue_size,
            engine=self.engine,
        )
        publish_stop = asyncio.Event()
        pub_task = asyncio.create_task(publisher.run(publish_stop), name=f"publisher-{self.id}")
        control_stop = asyncio.Event()  # the device's end (a replay's too), not only the daemon's
        control_task: asyncio.Task[None] | None = None
        if self.mqtt.control:
            made_by = recording_metadata(settings, self.runtime)  # its MCAP files' record
            self.control = Control(self.mqtt, self.id, pipeline, made_by)
            control_task = asyncio.create_task(
                self.control.run(control_stop), name=f"control-{self.id}"
            )
        pipe_task = asyncio.create_task(
            pipeline.run(self._on_prediction, self._on_state, stop), name=f"pipeline-{self.id}"
        )
        health = asyncio.create_task(self._health_loop(stop), name=f"health-{self.id}")
        exit_code = 0
        try:  # the pipeline ends on ``stop`` or when its source does (a replay's end)
            await pipe_task
        except Exception:
            log.exception("device %s: pipeline failed", self.id)
            exit_code = 1
        finally:
            if self.recorder is not None:
                self.recorder.close()
        deadline = time.monotonic() + settings.stop_timeout_s
        if control_task is not None and self.control is not None:
            control_stop.set()
            await asyncio.gather(control_task, return_exceptions=True)
            await self.control.close()  # what record/start opened: the files' last bytes
        publisher.on_drained = self._publish_final_state
        publish_stop.set()
        try:
            await asyncio.wait_for(pub_task, _left(deadline))
        except TimeoutError:
            log.warning("device %s: publisher did not drain within the stop timeout", self.id)
        health.cancel()
        await asyncio.gather(health, return_exceptions=True)
        seconds = time.monotonic() - self.started_mono
        pairs = self.counters.pairing.pairs_out
        log.info(
            "device %s: stopped: %d paired frames in %.1f s (%.0f frames/s), %d published",
            self.id,
            pairs,
            seconds,
            pairs / seconds if seconds > 0 else 0.0,
            publisher.stats.published,
        )
        return exit_code

    # --- callbacks from the pipeline and the publisher ------------------------------
    def _on_prediction(self, prediction: Prediction) -> None:
        """The one result object, as it is, to each consumer (none of them changes it)."""
        assert self.publisher is not None
        self.publisher.submit(prediction)  # encoded when it is published
        self.outputs.prediction(prediction)  # queued only: written on the outputs' thread
        if self.control is not None:
            self.control.prediction(prediction)  # an MCAP file record/start opened

    def _on_state(self, state: PipelineState) -> None:
        self.state = state
        self._publish_status()
        self.on_change(self)

    def _on_broker_state(self, state: BrokerState, detail: str) -> None:
        self._publish_status()  # the outputs beside MQTT (web, Foxglove) show the outage
        self.on_change(self)

    def _on_status_published(self, status: Status) -> None:
        """Said in the log once the broker has acknowledged it, never before."""
        key = (status.state, tuple(status.reasons))
        if key == self._logged_status:
            return  # republished after a reconnect: said already
        self._logged_status = key
        shown = f": {', '.join(status.reasons)}" if status.reasons else ""
        log.info("%sstatus %s%s", self._log_prefix, status.state, shown)

    def _publish_status(self) -> None:
        state = self.state
        if state is None or self.publisher is None:
            return
        reasons = list(state.reasons)
        frames, needed = state.warming
        if frames < needed and state.source == "connected":
            reasons.append("warming up")  # how far: Status.warming (not a new status per frame)
        key = (state.source, tuple(sorted(state.feet.items())), tuple(reasons))
        broker_away = self.publisher.state == "disconnected"
        if (key, broker_away) == self._status_key:
            return  # unchanged: no retained republish at 16 Hz
        changed = self._status_key is None or key != self._status_key[0]
        self._status_key = (key, broker_away)
        st: Literal["online", "degraded"] = "degraded" if reasons else "online"
        status: Status = messages.status(st, reasons, state)
        if changed:  # the broker's coming and going is no news on MQTT (it republishes)
            self.publisher.set_status(status)
        if broker_away:  # the other outputs (web view, Foxglove, MCAP) show the outage
            shown = [*reasons, f"broker unreachable ({self.publisher.stats.last_error})"]
            status = messages.status("degraded", shown, state)
        self.outputs.status(status)
        if self.control is not None:
            self.control.status(status)

    @property
    def _log_prefix(self) -> str:
        return "" if self.settings.source is not None else f"device {self.id}: "

    def _publish_final_state(self) -> None:
        assert self.publisher is not None
        final = messages.status("offline", ["stopped"], self.state)
        # To the outputs before the last health is taken: queueing it may drop one more
        # prediction there, and the last health counts it.
        self.outputs.status(final)
        self.publisher.set_health(self.health())
        self.publisher.set_status(final)

    # --- health -------------------------------------------------------------------------
    async def _health_loop(self, stop: asyncio.Event) -> None:
        interval = self.mqtt.health_interval_s
        while not stop.is_set():
            await wait_event(stop, interval)
            if self.publisher is not None and not stop.is_set():
                self.publisher.set_health(self.health())

    def health(self) -> Any:
        assert self.publisher is not None
        health = messages.health(
            self.counters.snapshot(),
            self.publisher,
            uptime_s=time.monotonic() - self.started_mono,
            outputs_dropped=self.outputs.dropped,
            outputs_errors=self.outputs.errors,
        )
        # Under ``pipeline`` (open in the schema), as the outputs' counts are. The engine's
        # counts are the daemon's (every device's frames), the same on each device.
        pipeline = {**health.pipeline, "engine": self.engine.stats()}
        if servers := self.outputs.servers:  # who is connected to the web and Foxglove
            pipeline["outputs"] = {**pipeline["outputs"], "servers": servers}
        if self.control is not None:
            pipeline["control"] = self.control.stats.as_dict()
        return health.model_copy(update={"pipeline": pipeline})


class _PacedByPublisher:
    """A source that can wait (replay), held back while the publish queue is nearly full.

    Each chunk may complete a frame whose prediction lands in the queue only after
    the inference worker's backlog, so room is kept for that backlog too."""

    def __init__(self, source: Source, publisher: Publisher, backlog: int) -> None:
        self.source = source
        self.publisher = publisher
        self.backlog = backlog
        self.name = source.name
        self.live = source.live

    async def stream(self) -> AsyncGenerator[SourceItem, None]:
        async with contextlib.aclosing(self.source.stream()) as items:
            async for item in items:
                await self.publisher.wait_room(self.backlog)
                yield item


def _left(deadline: float) -> float:
    return max(0.05, deadline - time.monotonic())
