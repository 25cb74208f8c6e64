"""The MCAP file a remote-control ``record/start`` opens: one device's Foxglove
channels plus ``/events``, the marks ``event/mark`` puts into it.

Written on a thread of its own, as the daemon's other outputs are; the
``[outputs]`` extra's packages are imported only when a recording asks for them.
"""

from __future__ import annotations

import asyncio
import importlib.util
import logging
import time
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final

from scotti.daemon.outputs import EXTRA_HINT
from scotti.firmware_protocol.session import EventRecord

if TYPE_CHECKING:
    from scotti.daemon.frames.pipeline import Prediction
    from scotti.daemon.mqtt.schemas import Status
    from scotti.daemon.outputs.fanout import Item, OutputThread
    from scotti.daemon.outputs.foxglove_out import FoxgloveOutput

log = logging.getLogger("scotti.daemon.mqtt.control")

MCAP_CLOSE_TIMEOUT_S: Final = 5.0
EVENTS_TOPIC: Final = "/events"  # the MCAP channel of the marked events
# Flat (no $ref, $defs or anyOf), as Foxglove's JSON Schema parser wants it.
EVENT_CHANNEL_SCHEMA: Final[dict[str, Any]] = {
    "type": "object",
    "properties": {
        "label": {"type": "string"},
        "detail": {"type": "string"},
        "seq": {"type": "integer", "description": "newest prediction's seq, -1: none yet"},
        "host_wall_ns": {"type": "integer"},
        "host_mono_ns": {"type": "integer"},
    },
}


def mcap_missing() -> str | None:
    """Why an MCAP file cannot be written here, or None when it can."""
    if importlib.util.find_spec("foxglove") is None:
        return f"no MCAP file: it needs the Python package 'foxglove': {EXTRA_HINT}"
    return None


class McapRecording:
    """One device's Foxglove channels into an MCAP file, written on a thread of its own
    (as the daemon's other outputs are), plus ``/events``."""

    def __init__(self, path: Path, device: str, metadata: Mapping[str, str] | None) -> None:
        # The [outputs] extra's: imported only when a recording asks for them.
        import foxglove
        from scotti.daemon.outputs.fanout import Item, OutputThread
        from scotti.daemon.outputs.foxglove_out import FoxgloveOutput

        self._item = Item
        self.device = device
        self.output: FoxgloveOutput = FoxgloveOutput(
            mcap=path, port=None, devices=(device,), metadata=metadata
        )
        assert self.output.mcap_path is not None
        self.path: Path = self.output.mcap_path
        self._events = foxglove.Channel(
            EVENTS_TOPIC, schema=EVENT_CHANNEL_SCHEMA, context=self.output.context
        )
        self._thread: OutputThread = OutputThread(self._handle, devices=1)

    def prediction(self, p: Prediction) -> None:
        self._thread.submit(self._item(self.device, prediction=p))

    def status(self, status: Status) -> None:
        self._thread.submit(self._item(self.device, status=status))

    def event(self, record: EventRecord, seq: int | None) -> bool:
        """Log one event (a small JSON message; the SDK's channels take it from any thread)."""
        try:
            self._events.log(
                {
                    "label": record.label,
                    "detail": record.detail,
                    "seq": -1 if seq is None else seq,
                    "host_wall_ns": record.wall_ns,
                    "host_mono_ns": record.t_ns,
                },
                log_time=record.wall_ns,
            )
        except Exception:
            log.warning("remote control: event not written to %s", self.path, exc_info=True)
            return False
        return True

    def _handle(self, item: Item) -> None:  # on the thread
        p = item.prediction
        if p is not None:
            latency_ms = (time.monotonic_ns() - (p.last_byte_mono_ns or p.host_mono_ns)) / 1e6
            self.output.prediction(self.device, p, latency_ms)
        elif item.status is not None:
            self.output.status(self.device, item.status)

    def close(self) -> None:
        """Write what is queued, then the file's index. Blocks: from a worker thread."""
        if not self._thread.close(MCAP_CLOSE_TIMEOUT_S):
            log.warning(
                "remote control: %s: %d items not written", self.path, self._thread.abandoned
            )
        # ``FoxgloveOutput.close`` is a coroutine that never awaits: run here, off the loop.
        asyncio.run(self.output.close())
