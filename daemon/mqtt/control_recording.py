"""The files remote control records into: ``record/start`` opens a session file (and,
with the ``[outputs]`` extra, an MCAP file of the Foxglove channels), ``record/stop``
closes what is recording, ``event/mark`` writes an event record into both.

Each request's outcome is the fields of an ok reply, or the reason it was refused (a
``str``); ``control.Control`` turns it into the reply and counts it.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from scotti.daemon.input.recording import Recorder, RecordingError
from scotti.daemon.mqtt.schemas import Event, EventMark, RecordStart
from scotti.daemon.outputs import OutputError
from scotti.daemon.outputs.event_mcap import McapRecording, mcap_missing
from scotti.firmware_protocol.session import EventRecord

if TYPE_CHECKING:
    from pathlib import Path

    from scotti.daemon.frames.pipeline import Pipeline, Prediction
    from scotti.daemon.mqtt.schemas import Status

Outcome = dict[str, Any] | str  # an ok reply's fields, or why it was refused


@dataclass
class _Recording:
    """What ``record/start`` opened."""

    session: Recorder
    mcap: McapRecording | None
    started_mono: float


class ControlRecordings:
    """The recordings of one device's remote control, into ``folder``."""

    def __init__(
        self,
        folder: Path,
        device_id: str,
        pipeline: Pipeline,
        mcap_metadata: Mapping[str, str] | None = None,
    ) -> None:
        self.folder = folder
        self.device_id = device_id
        self.pipeline = pipeline
        self.mcap_metadata = mcap_metadata
        self._recording: _Recording | None = None
        self._status: Status | None = None

    # --- from the device (event loop, never blocks) ------------------------------
    def prediction(self, p: Prediction) -> None:
        if self._recording is not None and self._recording.mcap is not None:
            self._recording.mcap.prediction(p)

    def status(self, status: Status) -> None:
        self._status = status
        if self._recording is not None and self._recording.mcap is not None:
            self._recording.mcap.status(status)

    # --- requests ------------------------------------------------------------------
    async def start(self, request: RecordStart) -> Outcome:
        current = self.pipeline.recorder
        if current is not None and current.is_open:
            return f"already recording to {current.path}; record/stop first"
        missing = mcap_missing()
        if request.mcap is True and missing is not None:
            return missing
        folder = self.folder
        target = folder / f"{request.name}.scotti" if request.name else folder
        try:
            session = await asyncio.to_thread(Recorder, target, device=self.device_id)
        except RecordingError as exc:
            return str(exc)
        mcap: McapRecording | None = None
        if request.mcap is not False and missing is None:
            try:
                mcap = await asyncio.to_thread(
                    McapRecording,
                    session.path.with_suffix(".mcap"),
                    self.device_id,
                    self.mcap_metadata,
                )
            except OutputError as exc:  # all or nothing: the session file goes too
                await asyncio.to_thread(session.close)
                session.path.unlink(missing_ok=True)
                return str(exc).removeprefix("--record-mcap: ")
            if self._status is not None:
                mcap.status(self._status)  # the file starts with the device's state
        self._recording = _Recording(session, mcap, time.monotonic())
        self.pipeline.recorder = session
        note = missing if request.mcap is None else None
        return {
            "session": str(session.path),
            "mcap": str(mcap.path) if mcap else None,
            "note": note,
        }

    async def stop(self) -> Outcome:
        session = self.pipeline.recorder
        ours = self._recording
        if session is None:
            return "nothing is recording"
        self.pipeline.recorder = None
        self._recording = None if ours is None or ours.session is session else ours
        mcap = ours.mcap if ours is not None and ours.session is session else None
        await asyncio.to_thread(session.close)
        if mcap is not None:
            await asyncio.to_thread(mcap.close)
        if session.failed:  # the disk filled or the file went away while recording
            return session.failed
        seconds = time.monotonic() - ours.started_mono if ours is not None else None
        return {
            "session": str(session.path),
            "mcap": str(mcap.path) if mcap is not None else None,
            "seconds": round(seconds, 3) if seconds is not None else None,
            "events": session.events,
        }

    def mark(self, request: EventMark, seq: int | None) -> tuple[Event, dict[str, Any]]:
        """The event record, put at frame ``seq``, in what is recording: the event to echo
        on the event topic, and the ok reply's fields."""
        mono, wall = time.monotonic_ns(), time.time_ns()
        written: list[str] = []
        session = self.pipeline.recorder
        record = EventRecord(mono, request.label, request.detail, wall)
        if session is not None and session.mark(record):
            written.append(str(session.path))
        ours = self._recording
        if ours is not None and ours.mcap is not None and ours.mcap.event(record, seq):
            written.append(str(ours.mcap.path))
        event = Event(
            label=request.label,
            detail=request.detail,
            seq=seq,
            host_wall_ns=wall,
            host_mono_ns=mono,
            written_to=written,
        )
        note = None if written else "not recording: echoed on the event topic only"
        return event, {"seq": seq, "written_to": written, "note": note}

    # --- the end -----------------------------------------------------------------------
    async def close(self) -> None:
        """Close what ``record/start`` opened (the files' last bytes, the MCAP index)."""
        ours, self._recording = self._recording, None
        if ours is None:
            return
        if self.pipeline.recorder is ours.session:
            self.pipeline.recorder = None
        await asyncio.to_thread(ours.session.close)
        if ours.mcap is not None:
            await asyncio.to_thread(ours.mcap.close)
