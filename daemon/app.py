"""The daemon's life: start, run, graceful stop.

Start: the model is already loaded (main.py); open the source, start the
publisher (it keeps trying while the broker is away). Run: the pipeline
reads, predicts and hands each prediction to the publisher's queue; a timer
publishes health; the systemd watchdog is patted from this loop. Stop:
SIGTERM/SIGINT set an event (a replay ending does too), the pipeline winds
down, ``offline`` is published, the queue drained and the recording closed,
all within ``stop_timeout_s``.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import platform
import signal
import time
from collections.abc import AsyncGenerator
from importlib import metadata
from typing import Any, Final, Literal

import numpy as np
from pydantic import BaseModel
from scotti.daemon import loop_errors, messages
from scotti.daemon.counters import Counters
from scotti.daemon.notify import Notifier
from scotti.daemon.outputs import Outputs
from scotti.daemon.pipeline import Pipeline, PipelineState, Prediction
from scotti.daemon.publisher import BrokerState, FrameBatch, Publisher
from scotti.daemon.recording import Recorder
from scotti.daemon.schemas import Status
from scotti.daemon.settings import Settings
from scotti.daemon.sources import ReplaySource, SerialSource, Source, SourceItem
from scotti.daemon.sources_sim import SimulatedSource
from scotti.daemon.waiting import wait_event
from scotti.models.runtime import ScottiRuntime

log = logging.getLogger(__name__)


class Daemon:
    """One run of the service; ``await Daemon(settings, runtime).run()`` -> exit status."""

    def __init__(
        self, settings: Settings, runtime: ScottiRuntime, notifier: Notifier | None = None
    ) -> None:
        self.settings = settings
        self.runtime = runtime
        self.notifier = notifier or Notifier()
        self.counters = Counters()
        self.started_mono = time.monotonic()
        self._state: PipelineState | None = None
        self._status_key: tuple[object, ...] | None = None
        self._ready = False
        self._sd_status = ""
        self._stop = asyncio.Event()
        self._publisher: Publisher | None = None
        self._outputs = Outputs()  # MCAP, Foxglove, LSL, web: each prediction and status

    @property
    def publisher(self) -> Publisher | None:
        """The MQTT side while running (its stats: published, dropped), else None."""
        return self._publisher

    async def run(self) -> int:
        # First, before anything has started: a scene or recording that cannot be
        # used is a one-line error (SourceError, RecordingError).
        source = self._make_source()
        recorder = self._make_recorder()
        try:  # MCAP, Foxglove, LSL, web: a port in use is a one-line error too
            self._outputs = await Outputs.open(
                self.settings.outputs, title=self.settings.mqtt.device_id
            )
        except BaseException:
            if recorder is not None:
                recorder.close()
            raise
        loop = asyncio.get_running_loop()
        loop_errors.install(loop, logging.getLogger("scotti.daemon.mqtt"))
        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(sig, self._on_signal, sig)
        publisher = Publisher(
            self.settings.mqtt,
            info=messages.info(
                self.settings, self.runtime, _versions(), recorder.path if recorder else None
            ),
            will=messages.status("offline", ["connection lost (last will)"], None),
        )
        self._publisher = publisher
        publisher.on_state_change = self._on_broker_state
        publisher.set_status(messages.status("degraded", ["starting"], None))
        if not source.live:  # a replay waits for the broker rather than lose predictions
            source = _PacedByPublisher(source, publisher)
        pipeline = Pipeline(source, self.runtime, self.counters, recorder)
        publish_stop = asyncio.Event()
        pub_task = asyncio.create_task(publisher.run(publish_stop), name="publisher")
        pipe_task = asyncio.create_task(
            pipeline.run(self._on_prediction, self._on_state, self._stop), name="pipeline"
        )
        helpers = [
            asyncio.create_task(self._health_loop(), name="health"),
            asyncio.create_task(self.notifier.watchdog_loop(self._stop), name="watchdog"),
        ]
        exit_code = 0
        stop_waiter = asyncio.create_task(self._stop.wait())
        await asyncio.wait([pipe_task, stop_waiter], return_when=asyncio.FIRST_COMPLETED)
        stop_waiter.cancel()
        self.notifier.stopping()
        self._stop.set()
        deadline = time.monotonic() + self.settings.stop_timeout_s
        try:
            await asyncio.wait_for(pipe_task, _left(deadline))
        except TimeoutError:
            log.warning("pipeline did not stop within %.1f s", self.settings.stop_timeout_s)
        except Exception:
            log.exception("pipeline failed")
            exit_code = 1
        finally:
            if recorder is not None:
                recorder.close()
        publisher.on_drained = self._publish_final_state
        publish_stop.set()
        try:
            await asyncio.wait_for(pub_task, _left(deadline))
        except TimeoutError:
            log.warning("publisher did not drain within the stop timeout")
        for task in helpers:
            task.cancel()
        await asyncio.gather(*helpers, return_exceptions=True)
        await self._outputs.close()
        self.notifier.close()
        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.remove_signal_handler(sig)
        seconds = time.monotonic() - self.started_mono
        pairs = self.counters.pairing.pairs_out
        log.info(
            "stopped: %d paired frames in %.1f s (%.0f frames/s), %d predictions published",
            pairs,
            seconds,
            pairs / seconds if seconds > 0 else 0.0,
            publisher.stats.published,
        )
        return exit_code

    # --- construction -----------------------------------------------------------
    def _make_source(self) -> Source:
        src = self.settings.source
        if src.port is not None:
            return SerialSource(src.port)
        if src.replay is not None:
            return ReplaySource(src.replay, speed=src.speed)
        assert src.simulate is not None
        return SimulatedSource(src.simulate, speed=src.speed)  # a scene on an emulated board

    def _make_recorder(self) -> Recorder | None:
        if self.settings.record is None:
            return None
        return Recorder(self.settings.record, device=self.settings.mqtt.device_id)

    # --- callbacks from the pipeline and the publisher ------------------------------
    def _on_signal(self, sig: signal.Signals) -> None:
        if self._stop.is_set():
            return
        log.info("%s: stopping", sig.name)
        self._stop.set()

    def _on_prediction(self, prediction: Prediction) -> None:
        assert self._publisher is not None
        self._outputs.prediction(prediction)
        pressure = self.settings.mqtt.pressure_downsample if self.settings.mqtt.pressure else 0

        def render(latency_ms: float) -> list[tuple[str, BaseModel]]:
            return messages.frame_payloads(prediction, latency_ms, pressure)

        self._publisher.submit(
            FrameBatch(
                seq=prediction.seq,
                last_byte_mono_ns=prediction.last_byte_mono_ns,
                made_mono_ns=prediction.host_mono_ns,
                render=render,
            )
        )

    def _on_state(self, state: PipelineState) -> None:
        self._state = state
        if not self._ready and state.source == "connected":
            self._ready = True
            self._sd_status = self._systemd_status()
            self.notifier.ready(self._sd_status)
        self._publish_status()

    def _on_broker_state(self, state: BrokerState, detail: str) -> None:
        self._notify_status()

    def _notify_status(self) -> None:
        text = self._systemd_status()
        if text != self._sd_status:
            self._sd_status = text
            self.notifier.status(text)

    def _publish_status(self) -> None:
        state = self._state
        if state is None or self._publisher is None:
            return
        reasons = list(state.reasons)
        frames, needed = state.warming
        if frames < needed and state.source == "connected":
            reasons.append("warming up")  # how far: Status.warming (not a new status per frame)
        key = (state.source, tuple(sorted(state.feet.items())), tuple(reasons))
        if key == self._status_key:
            return  # unchanged: no retained republish at 16 Hz
        self._status_key = key
        st: Literal["online", "degraded"] = "degraded" if reasons else "online"
        status: Status = messages.status(st, reasons, state)
        self._publisher.set_status(status)
        self._outputs.status(status)
        log.info("status %s%s", st, f": {', '.join(reasons)}" if reasons else "")
        self._notify_status()

    def _publish_final_state(self) -> None:
        assert self._publisher is not None
        self._publisher.set_health(self._health())
        final = messages.status("offline", ["stopped"], self._state)
        self._publisher.set_status(final)
        self._outputs.status(final)

    def _systemd_status(self) -> str:
        broker = self._publisher.detail if self._publisher else "starting"
        source = self._state.source if self._state else "starting"
        return f"source {source}, broker {broker}"

    # --- health -------------------------------------------------------------------------
    async def _health_loop(self) -> None:
        interval = self.settings.mqtt.health_interval_s
        while not self._stop.is_set():
            await wait_event(self._stop, interval)
            if self._publisher is not None and not self._stop.is_set():
                self._publisher.set_health(self._health())

    def _health(self) -> Any:
        assert self._publisher is not None
        return messages.health(
            self.counters.snapshot(),
            self._publisher,
            uptime_s=time.monotonic() - self.started_mono,
        )


class _PacedByPublisher:
    """A source that can wait (replay), held back while the publish queue is nearly full.

    Each chunk may complete a frame whose prediction lands in the queue only after
    the inference worker's backlog, so room is kept for that backlog too."""

    def __init__(self, source: Source, publisher: Publisher) -> None:
        self.source = source
        self.publisher = publisher
        self.name = source.name
        self.live = source.live

    async def stream(self) -> AsyncGenerator[SourceItem, None]:
        async with contextlib.aclosing(self.source.stream()) as items:
            async for item in items:
                await self.publisher.wait_room(_INFERENCE_BACKLOG)
                yield item


_INFERENCE_BACKLOG: Final = 18  # the pipeline's worker queue (16) and a frame or two more


def _left(deadline: float) -> float:
    return max(0.05, deadline - time.monotonic())


def _versions() -> dict[str, str]:
    out = {"python": platform.python_version(), "numpy": np.__version__}
    for dist in ("scotti", "onnxruntime", "aiomqtt", "pydantic", "paho-mqtt"):
        with contextlib.suppress(metadata.PackageNotFoundError):
            out[dist] = metadata.version(dist)
    return out
