"""Outputs beside MQTT: MCAP files and Foxglove live, Lab Streaming Layer, a browser view.

The daemon hands every output the same two things it hands each device's
MQTT publisher: each ``Prediction`` (pose, action probabilities, progress,
repetition, stamps and the raw counts of the frame that made it) and each
``Status``, with the id of the device it came from. One set of outputs
serves every device of the daemon: one MCAP file and one Foxglove server
with channels per device, LSL outlets per device, one web server with a
page per device. With a single device the names are those of a one-pair
daemon (``/skeleton``, not ``/<id>/skeleton``); see ``device_prefix``.

A device only queues what it hands over (``fanout.OutputThread``); the
outputs do their work on their own thread, so they never hold up a reader or
a publisher. An output that fails is counted and logged once, never allowed
to stall or kill anything; the libraries an output needs come with the
``[outputs]`` extra and are imported only when that output is asked for, so
the daemon runs without them.
"""

from __future__ import annotations

import asyncio
import importlib
import json
import logging
import time
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any, Final, Protocol

from scotti.daemon.errors import DaemonError
from scotti.daemon.outputs import guard
from scotti.daemon.outputs.fanout import Item, OutputThread

if TYPE_CHECKING:
    from scotti.daemon.frames.pipeline import Prediction
    from scotti.daemon.mqtt.schemas import Status
    from scotti.daemon.settings import Settings
    from scotti.daemon.settings.outputs import OutputSettings
    from scotti.models.kv_streaming import StepModel

log = logging.getLogger(__name__)

EXTRA_HINT = "pip install 'scotti[outputs]'"
CLOSE_TIMEOUT_S: Final = 5.0  # to write what is still queued when the daemon stops


class OutputError(DaemonError):
    """An output that cannot start (a port in use, a file that cannot be written, a
    library that is not installed): one line for the user."""


class Output(Protocol):
    """Called on the outputs' thread (never the event loop's), one item at a time."""

    name: str

    def prediction(self, device: str, p: Prediction, latency_ms: float) -> None: ...

    def status(self, device: str, status: Status) -> None: ...

    async def close(self) -> None: ...


def device_prefix(device: str, devices: Sequence[str]) -> str:
    """What a device's names start with: nothing for a lone device (the names a one-pair
    daemon always had), ``<id>/`` when the daemon serves several."""
    return f"{device}/" if len(devices) > 1 else ""


def recording_metadata(settings: Settings, runtime: StepModel) -> dict[str, str]:
    """The ``scotti`` metadata record of a live MCAP file: the model that made it (file
    and sha256, as an export names it) and the daemon's settings (``info``'s, no secret)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        scotti_version = version("scotti")
    except PackageNotFoundError:  # a source tree that was never installed
        scotti_version = "unknown"
    return {
        "source": "live",
        "devices": ",".join(d.id for d in settings.device_list()),
        "model": runtime.path.name,
        "model_sha256": runtime.sha256,
        "config": json.dumps(settings.summary(), sort_keys=True, default=str),
        "scotti_version": scotti_version,
    }


def require(module: str, what: str) -> None:
    """Import ``module`` or say which extra brings it (one line, no traceback)."""
    try:
        importlib.import_module(module)
    except ImportError as exc:
        msg = f"{what} needs the Python package {exc.name or module!r}: {EXTRA_HINT}"
        raise OutputError(msg) from None
    except Exception as exc:  # installed but broken: pylsl without its liblsl raises this
        reason = " ".join(str(exc).split())  # one line, whatever the library wrote
        msg = f"{what}: the Python package {module!r} cannot be loaded: {reason}"
        raise OutputError(msg) from None


def rules_of(settings: OutputSettings) -> guard.Rules:
    """Who may connect to the Foxglove and web servers (``guard``), from ``[outputs]``."""
    token = settings.token.get_secret_value() if settings.token is not None else None
    return guard.Rules(
        max_connections=settings.max_connections,
        bound_host=settings.host,
        allowed_hosts=settings.allowed_hosts,
        allowed_origins=settings.allowed_origins,
        token=token,
    )


class Outputs:
    """The outputs of one daemon run; ``prediction`` and ``status`` are called from the
    event loop and return at once."""

    def __init__(self, outputs: Sequence[Output] = (), devices: Sequence[str] = ()) -> None:
        self.outputs = list(outputs)
        self.devices = tuple(devices)
        self.errors: dict[str, int] = {o.name: 0 for o in self.outputs}
        # The same failures by device, for each device's ``health`` (written on the
        # outputs' thread, read from the loop: a dict of ints, no lock needed).
        self._errors_by_device: dict[str, dict[str, int]] = {
            d: {o.name: 0 for o in self.outputs} for d in self.devices
        }
        # No thread without outputs, nor without devices (what ``open`` closes on a failure).
        started = self.outputs and self.devices
        self._thread = OutputThread(self._handle, devices=len(devices)) if started else None
        self._closed = False

    @classmethod
    async def open(
        cls,
        settings: OutputSettings,
        devices: Sequence[str],
        metadata: Mapping[str, str] | None = None,
    ) -> Outputs:
        """Start what ``settings`` asks for, for every device in ``devices``;
        ``OutputError`` when one cannot start. ``metadata``: what a recording says made
        it (``recording_metadata``), the MCAP file's ``scotti`` record."""
        opened: list[Output] = []
        rules = rules_of(settings)
        try:
            if settings.record_mcap is not None or settings.foxglove is not None:
                require("foxglove", "--record-mcap / --foxglove")
                from scotti.daemon.outputs.foxglove_out import FoxgloveOutput

                opened.append(
                    FoxgloveOutput(
                        mcap=settings.record_mcap,
                        port=settings.foxglove,
                        host=settings.host,
                        devices=devices,
                        metadata=metadata,
                        rules=rules,
                    )
                )
            if settings.lsl:
                require("pylsl", "--lsl")
                from scotti.daemon.outputs.lsl import LslOutput

                try:
                    opened.append(LslOutput(devices))
                except Exception as exc:  # liblsl's own errors (a network it cannot use)
                    msg = f"--lsl: cannot open the outlets: {exc}"
                    raise OutputError(msg) from None
            if settings.web is not None:
                from scotti.daemon.outputs.web import WebOutput

                web = await WebOutput.start(settings.host, settings.web, devices, rules)
                opened.append(web)
        except BaseException:
            await cls(opened).close()  # no thread yet (no devices): closes at once
            raise
        for output in opened:
            log.info("output %s", output)
        return cls(opened, devices)

    @property
    def dropped(self) -> int:
        """Predictions the outputs never saw because they fell behind (after ``close``
        too: the count is the run's)."""
        return self._thread.dropped if self._thread is not None else 0

    def dropped_of(self, device: str) -> int:
        """The predictions of ``device`` among ``dropped``: its ``health`` reports them."""
        return self._thread.dropped_of(device) if self._thread is not None else 0

    def errors_of(self, device: str) -> dict[str, int]:
        """Times each output failed on one of ``device``'s predictions or statuses."""
        return dict(self._errors_by_device.get(device, {}))

    @property
    def servers(self) -> dict[str, dict[str, Any]]:
        """Per network output (web, Foxglove) its server's counts: connections now, the
        cap, refusals by reason (over the cap, Host, Origin, token, ...); the daemon's, the
        same for every device."""
        counts = {o.name: getattr(o, "counters", None) for o in self.outputs}
        return {name: dict(c) for name, c in counts.items() if c}

    def of(self, device: str) -> DeviceOutputs:
        """What one device calls."""
        return DeviceOutputs(self, device)

    def prediction(self, device: str, p: Prediction) -> None:
        if self._thread is not None:
            self._thread.submit(Item(device, prediction=p))

    def status(self, device: str, status: Status) -> None:
        if self._thread is not None:
            self._thread.submit(Item(device, status=status))

    async def close(self) -> None:
        """Write what is queued (each device's last status too), then close every output."""
        if self._closed:
            return
        self._closed = True  # the thread is kept for its counts; it takes nothing more
        if self._thread is not None:
            thread = self._thread
            if not await asyncio.to_thread(thread.close, CLOSE_TIMEOUT_S):
                log.warning(
                    "outputs did not write their queue within %.0f s: %d items given up",
                    CLOSE_TIMEOUT_S,
                    thread.abandoned,
                )
        for output in self.outputs:
            try:
                await output.close()
            except Exception:
                log.warning("output %s did not close cleanly", output.name, exc_info=True)

    def _handle(self, item: Item) -> None:  # on the outputs' thread
        p = item.prediction
        latency_ms = 0.0
        if p is not None:  # from the frame's last byte to now, the queue's wait included
            latency_ms = (time.monotonic_ns() - (p.last_byte_mono_ns or p.host_mono_ns)) / 1e6
        for output in self.outputs:
            try:
                if p is not None:
                    output.prediction(item.device, p, latency_ms)
                elif item.status is not None:
                    output.status(item.device, item.status)
            except Exception:  # an output never kills the others, nor the daemon
                self._failed(output, item.device)

    def _failed(self, output: Output, device: str) -> None:
        self.errors[output.name] += 1
        by_output = self._errors_by_device.setdefault(device, {})
        by_output[output.name] = by_output.get(output.name, 0) + 1
        if self.errors[output.name] == 1:
            log.warning("output %s failed (counted from now on)", output.name, exc_info=True)


class DeviceOutputs:
    """One device's side of ``Outputs``: hands its predictions and statuses over."""

    def __init__(self, outputs: Outputs | None, device: str) -> None:
        self.outputs = outputs
        self.device = device

    def prediction(self, p: Prediction) -> None:
        if self.outputs is not None:
            self.outputs.prediction(self.device, p)

    def status(self, status: Status) -> None:
        if self.outputs is not None:
            self.outputs.status(self.device, status)

    @property
    def dropped(self) -> int:
        """This device's predictions the outputs dropped because they fell behind."""
        return self.outputs.dropped_of(self.device) if self.outputs is not None else 0

    @property
    def errors(self) -> dict[str, int]:
        """Per output, times it failed on this device's predictions or statuses."""
        return self.outputs.errors_of(self.device) if self.outputs is not None else {}

    @property
    def servers(self) -> dict[str, dict[str, Any]]:
        """``Outputs.servers``: the network outputs' connections and refusals."""
        return self.outputs.servers if self.outputs is not None else {}
