"""The daemon's life: start, run, graceful stop.

Start: the model is already loaded (main.py); open every device's source and
recording (a bad one is a one-line error before anything runs), start the
shared inference engine. Run: each device (``device.Device``) reads, predicts
through the engine and publishes on its own topics with its own client; the
systemd watchdog is patted from this loop. Stop: SIGTERM/SIGINT set an event
(the end of every device's replay does too), the devices wind down, each
publishes ``offline``, drains its queue and closes its recording, all within
``stop_timeout_s``; then the engine, the outputs and the rest close. An error or a
cancellation after the start takes the same way out (and then goes on unmasked).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import platform
import signal
import time
from collections.abc import Awaitable, Callable
from importlib import metadata
from typing import Any

import numpy as np
from scotti.daemon.inference.engine import InferenceEngine
from scotti.daemon.input.recording import Recorder
from scotti.daemon.input.simulated import SimulatedSource
from scotti.daemon.input.sources import ReplaySource, SerialSource, Source
from scotti.daemon.mqtt import messages
from scotti.daemon.mqtt.publisher import Publisher
from scotti.daemon.outputs import Outputs, recording_metadata
from scotti.daemon.service import loop_errors
from scotti.daemon.service.counters import Counters
from scotti.daemon.service.device import Device
from scotti.daemon.service.notify import Notifier
from scotti.daemon.settings import Settings
from scotti.daemon.settings.source import DeviceSettings
from scotti.models.kv_streaming import StepModel

log = logging.getLogger(__name__)

# How long a device cancelled at the end of the stop budget gets to run its cleanup.
CANCEL_GRACE_S = 2.0


class Daemon:
    """One run of the service; ``await Daemon(settings, runtime).run()`` -> exit status."""

    def __init__(
        self, settings: Settings, runtime: StepModel, notifier: Notifier | None = None
    ) -> None:
        self.settings = settings
        self.runtime = runtime
        self.notifier = notifier or Notifier()
        self.engine = InferenceEngine(
            batch=settings.inference.batch,
            max_batch=settings.inference.max_batch,
            gather_ms=settings.inference.gather_ms,
        )
        self.devices: list[Device] = []
        self.started_mono = time.monotonic()
        self._ready = False
        self._sd_status = ""
        self._stop = asyncio.Event()
        self._outputs = Outputs()  # MCAP, Foxglove, LSL, web: every device's predictions
        self._signals: list[signal.Signals] = []  # the handlers run added (and removes)
        self._helpers: list[asyncio.Task[Any]] = []  # the watchdog and the stop's waiter

    @property
    def counters(self) -> Counters:
        """The first device's counters: the one-pair daemon's, which its tools and tests read."""
        return self.devices[0].counters if self.devices else Counters()

    @property
    def publisher(self) -> Publisher | None:
        """The first device's MQTT side while running (its stats), else None."""
        return self.devices[0].publisher if self.devices else None

    async def run(self) -> int:
        # First, before anything has started: a scene or recording that cannot be
        # used is a one-line error (SourceError, RecordingError).
        try:
            wanted = self.settings.device_list()
            # Every source first: a bad scene must not leave empty recordings behind (a
            # source holds nothing until it streams).
            sources = [self._make_source(one) for one in wanted]
            for one, source in zip(wanted, sources, strict=True):
                recorder = self._make_recorder(one)
                self.devices.append(
                    Device(self.settings, one, self.runtime, self.engine, source, recorder)
                )
            # MCAP, Foxglove, LSL, web, one of each for all the devices (channels, outlets
            # and pages per device): a port in use is a one-line error
            ids = [device.id for device in self.devices]
            made_by = recording_metadata(self.settings, self.runtime)  # the MCAP file's
            self._outputs = await Outputs.open(self.settings.outputs, ids, made_by)
        except BaseException:
            self._close_recorders()
            raise
        # From here on every way out (the devices' end, a signal, an error, a cancellation)
        # goes through ``_close``: an output left open is an MCAP file without its index,
        # a bound port, a thread. On an error, the devices get the same graceful stop.
        tasks: list[asyncio.Task[int]] = []
        try:
            exit_code = await self._serve(tasks)
        except BaseException:
            try:
                await self._stop_devices(tasks)
            finally:
                await self._close()  # logs what fails in it: the run's own error goes on
            raise
        if not await self._close():
            exit_code = max(exit_code, 1)
        published = sum(d.publisher.stats.published for d in self.devices if d.publisher)
        log.info("stopped (%s predictions published)", published)
        return exit_code

    async def _serve(self, tasks: list[asyncio.Task[int]]) -> int:
        """Run every device until all have ended (replays) or a signal, then stop them;
        the exit status. ``tasks`` gets each device's task as it starts."""
        for device in self.devices:
            device.outputs = self._outputs.of(device.id)
        loop = asyncio.get_running_loop()
        loop_errors.install(loop, logging.getLogger("scotti.daemon.mqtt.paho"))
        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(sig, self._on_signal, sig)
            self._signals.append(sig)
        self.engine.start()
        versions = _versions()
        for device in self.devices:
            device.on_change = self._on_device_change
            settings = self.settings.model_copy(update={"mqtt": device.mqtt})
            recording = device.recorder.path if device.recorder else None
            info = messages.info(settings, self.runtime, versions, recording)
            tasks.append(asyncio.create_task(device.run(self._stop, info), name=device.id))
        watchdog = asyncio.create_task(self.notifier.watchdog_loop(self._stop), name="watchdog")
        self._helpers.append(watchdog)
        stop_waiter = asyncio.create_task(self._stop.wait())
        self._helpers.append(stop_waiter)
        # Until every device has ended (replays) or a signal: a device that ends or
        # fails leaves the others running.
        all_done: asyncio.Future[list[int | BaseException]] = asyncio.gather(
            *tasks, return_exceptions=True
        )
        waiting: list[asyncio.Future[Any]] = [all_done, stop_waiter]
        await asyncio.wait(waiting, return_when=asyncio.FIRST_COMPLETED)
        self.notifier.stopping()
        return await self._stop_devices(tasks)

    async def _stop_devices(self, tasks: list[asyncio.Task[int]]) -> int:
        """Set ``stop`` and give the devices the stop budget; the worst exit status.

        A device still running at the end of the budget is cancelled and gets
        ``CANCEL_GRACE_S`` to run its cleanup (its port, its MQTT client, its
        recording) before the engine and the outputs close under it; one whose
        cleanup hangs is left behind with a warning rather than hanging the stop.
        """
        self._stop.set()
        if not tasks:
            return 0
        budget = 2 * self.settings.stop_timeout_s + 1  # the pipeline's, then the publisher's
        _, late = await asyncio.wait(tasks, timeout=budget)
        if late:
            names = ", ".join(sorted(task.get_name() for task in late))
            log.warning("devices did not stop within %.1f s, cancelled: %s", budget, names)
            for task in late:
                task.cancel()
            _, stuck = await asyncio.wait(late, timeout=CANCEL_GRACE_S)
            if stuck:
                names = ", ".join(sorted(task.get_name() for task in stuck))
                log.warning("devices still running %.1f s after cancel: %s", CANCEL_GRACE_S, names)
        status = 0
        for task in tasks:
            if task in late or task.cancelled():
                status = max(status, 1)
            elif (error := task.exception()) is not None:
                log.error("device failed: %s", error)
                status = max(status, 1)
            else:
                status = max(status, task.result())
        return status

    async def _close(self) -> bool:
        """Close what ``run`` opened, each part even when one before it failed (logged,
        never raised: on an error path that would hide the error that ended the run);
        False when one failed."""
        steps: list[tuple[str, Callable[[], Awaitable[object] | None]]] = [
            ("recordings", self._close_recorders),
            ("watchdog", self._end_helpers),
            ("inference engine", self.engine.stop),
            ("outputs", self._outputs.close),
            ("systemd notifier", self.notifier.close),
            ("signal handlers", self._remove_signal_handlers),
        ]
        closed = True
        for what, step in steps:
            try:
                pending = step()
                if pending is not None:
                    await pending
            except Exception:
                log.exception("closing the %s failed", what)
                closed = False
        return closed

    async def _end_helpers(self) -> None:
        helpers, self._helpers = self._helpers, []
        for task in helpers:
            task.cancel()
        await asyncio.gather(*helpers, return_exceptions=True)

    def _remove_signal_handlers(self) -> None:
        loop = asyncio.get_running_loop()
        signals, self._signals = self._signals, []
        for sig in signals:
            loop.remove_signal_handler(sig)

    # --- construction -----------------------------------------------------------
    def _make_source(self, device: DeviceSettings) -> Source:
        if device.port is not None:
            return SerialSource(device.port)
        if device.replay is not None:
            return ReplaySource(device.replay, speed=device.speed)
        assert device.simulate is not None
        # A scene on a board, in a loop unless --once.
        return SimulatedSource(device.simulate, speed=device.speed, loop=not device.once)

    def _make_recorder(self, device: DeviceSettings) -> Recorder | None:
        path = device.record or self.settings.record
        if path is None:
            return None
        return Recorder(path, device=device.id)

    def _close_recorders(self) -> None:
        for device in self.devices:
            if device.recorder is not None:
                device.recorder.close()

    # --- callbacks ----------------------------------------------------------------------
    def _on_signal(self, sig: signal.Signals) -> None:
        if self._stop.is_set():
            return
        log.info("%s: stopping", sig.name)
        self._stop.set()

    def _on_device_change(self, device: Device) -> None:
        if not self._ready and device.state is not None and device.state.source == "connected":
            # READY once the model is loaded and a receiver is open: with several
            # devices, one is enough (the others report their own state on MQTT).
            self._ready = True
            self._sd_status = self._systemd_status()
            self.notifier.ready(self._sd_status)
            return
        text = self._systemd_status()
        if text != self._sd_status:
            self._sd_status = text
            self.notifier.status(text)

    def _systemd_status(self) -> str:
        if len(self.devices) == 1:
            device = self.devices[0]
            broker = device.publisher.detail if device.publisher else "starting"
            source = device.state.source if device.state else "starting"
            return f"source {source}, broker {broker}"
        connected = sum(1 for d in self.devices if d.state and d.state.source == "connected")
        brokers = sum(1 for d in self.devices if d.publisher and d.publisher.state == "connected")
        n = len(self.devices)
        return f"{connected} of {n} devices connected, {brokers} of {n} on the broker"


def _versions() -> dict[str, str]:
    out = {"python": platform.python_version(), "numpy": np.__version__}
    for dist in ("scotti", "onnxruntime", "aiomqtt", "pydantic", "paho-mqtt"):
        with contextlib.suppress(metadata.PackageNotFoundError):
            out[dist] = metadata.version(dist)
    return out
