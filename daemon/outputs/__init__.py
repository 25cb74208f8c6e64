"""Outputs beside MQTT: MCAP files and Foxglove live, Lab Streaming Layer, a browser view.

The daemon hands every output the same two things it hands the MQTT
publisher: each ``Prediction`` (pose, action probabilities, progress,
repetition, stamps and the raw counts of the frame that made it) and each
``Status``. ``Outputs`` fans them out. An output that fails is counted and
logged once, never allowed to stall or kill the pipeline; the libraries an
output needs come with the ``[outputs]`` extra and are imported only when
that output is asked for, so the daemon runs without them.
"""

from __future__ import annotations

import importlib
import logging
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING, Protocol

from scotti.daemon.errors import DaemonError

if TYPE_CHECKING:
    from scotti.daemon.outputs.settings import OutputSettings
    from scotti.daemon.pipeline import Prediction
    from scotti.daemon.schemas import Status

log = logging.getLogger(__name__)

EXTRA_HINT = "pip install 'scotti[outputs]'"


class OutputError(DaemonError):
    """An output that cannot start (a port in use, a file that cannot be written, a
    library that is not installed): one line for the user."""


class Output(Protocol):
    name: str

    def prediction(self, p: Prediction, latency_ms: float) -> None: ...

    def status(self, status: Status) -> None: ...

    async def close(self) -> None: ...


def require(module: str, what: str) -> None:
    """Import ``module`` or say which extra brings it (one line, no traceback)."""
    try:
        importlib.import_module(module)
    except ImportError as exc:
        msg = f"{what} needs the Python package {exc.name or module!r}: {EXTRA_HINT}"
        raise OutputError(msg) from None


class Outputs:
    """The outputs of one daemon run, called from the event loop thread."""

    def __init__(self, outputs: Sequence[Output] = ()) -> None:
        self.outputs = list(outputs)
        self.errors: dict[str, int] = {o.name: 0 for o in self.outputs}

    @classmethod
    async def open(cls, settings: OutputSettings, *, title: str = "scotti") -> Outputs:
        """Start what ``settings`` asks for; ``OutputError`` when one cannot start."""
        opened: list[Output] = []
        try:
            if settings.record_mcap is not None or settings.foxglove is not None:
                require("foxglove", "--record-mcap / --foxglove")
                from scotti.daemon.outputs.foxglove_out import FoxgloveOutput

                opened.append(
                    FoxgloveOutput(
                        mcap=settings.record_mcap, port=settings.foxglove, host=settings.host
                    )
                )
            if settings.lsl:
                require("pylsl", "--lsl")
                from scotti.daemon.outputs.lsl import LslOutput

                opened.append(LslOutput(title))
            if settings.web is not None:
                from scotti.daemon.outputs.web import WebOutput

                opened.append(await WebOutput.start(settings.host, settings.web))
        except BaseException:
            await cls(opened).close()
            raise
        for output in opened:
            log.info("output %s", output)
        return cls(opened)

    def prediction(self, p: Prediction) -> None:
        if not self.outputs:
            return
        origin = p.last_byte_mono_ns or p.host_mono_ns
        latency_ms = (time.monotonic_ns() - origin) / 1e6
        for output in self.outputs:
            try:
                output.prediction(p, latency_ms)
            except Exception:  # an output never kills the reader
                self._failed(output)

    def status(self, status: Status) -> None:
        for output in self.outputs:
            try:
                output.status(status)
            except Exception:
                self._failed(output)

    async def close(self) -> None:
        for output in self.outputs:
            try:
                await output.close()
            except Exception:
                log.warning("output %s did not close cleanly", output.name, exc_info=True)

    def _failed(self, output: Output) -> None:
        self.errors[output.name] += 1
        if self.errors[output.name] == 1:
            log.warning("output %s failed (counted from now on)", output.name, exc_info=True)
