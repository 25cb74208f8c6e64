"""``--record FILE``: the byte stream, before decoding, appended to a session file.

Each chunk read from the source becomes one packet record, written and
flushed on its own, so a daemon killed at any moment (kill -9, power cut)
leaves a file that reads back up to its last whole record. The OS is asked
to fsync every ``fsync_interval_s`` and on close.

A recording never stops the daemon: if the disk fills or the file goes away,
recording stops, the error is logged once and counted, the daemon goes on.

The daemon never overwrites a file, and it never picks a name of its own for
a name it was given (``recording_path``, also ``--record-mcap``'s): a fixed
name that exists is refused at the start (exit 78, one line with the hint).
A service that restarts asks for a new file at every start instead:
``{time}`` in the name is the UTC start time (``walk-{time}.scotti`` ->
``walk-20261121T135630.scotti``) and ``{device}`` the device id; a directory
gets a file named after the device and the UTC start time inside it
(``lab1-20261121T135630.scotti``). Only such a made name, taken already (two
starts within a second), gets ``.1``, ``.2``... before its suffix.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Iterator
from datetime import UTC, datetime
from pathlib import Path
from typing import Final

from scotti.daemon.errors import DaemonError
from scotti.firmware_protocol.errors import SessionError
from scotti.firmware_protocol.session import EventRecord, SessionHeader, SessionWriter

log = logging.getLogger(__name__)


class RecordingError(DaemonError):
    """The recording cannot start (directory missing, no permission); one line."""


PLACEHOLDERS: Final = ("{time}", "{device}")
_PLACEHOLDER = re.compile(r"\{[^{}/]*\}")


def stamp_of(now: datetime) -> str:
    """The UTC start time as names carry it: ``20261121T135630``."""
    return now.astimezone(UTC).strftime("%Y%m%dT%H%M%S")


def recording_path(requested: Path, device: str, now: datetime, suffix: str) -> tuple[Path, bool]:
    """The file to create for ``requested``, and whether its name was made (a directory,
    or a name with a placeholder) rather than given as it is.

    A directory gets ``<device>-<time><suffix>`` inside it; ``{time}`` and
    ``{device}`` in a name are filled in; any other ``{...}`` is a mistake."""
    if requested.is_dir():
        return requested / f"{device}-{stamp_of(now)}{suffix}", True
    name = requested.name
    unknown = [p for p in _PLACEHOLDER.findall(name) if p not in PLACEHOLDERS]
    if unknown:
        msg = f"{requested}: unknown placeholder {unknown[0]} (known: {', '.join(PLACEHOLDERS)})"
        raise RecordingError(msg)
    filled = name.replace("{time}", stamp_of(now)).replace("{device}", device)
    return requested.with_name(filled), filled != name


def taken_hint(path: Path) -> str:
    """The one line for a fixed name that exists: what to do instead."""
    with_time = path.with_name(f"{path.stem}-{{time}}{path.suffix}")
    return (
        f"{path} exists and is never overwritten; for a new file at every start put "
        f"{{time}} in the name ({with_time}) or give a directory, else move the file away"
    )


def candidate_paths(path: Path) -> Iterator[Path]:
    """A made name, then the same with ``.1``, ``.2``... before its suffix."""
    yield path
    n = 1
    while True:
        yield path.with_name(f"{path.stem}.{n}{path.suffix}")
        n += 1


def new_file(requested: Path, device: str, suffix: str) -> Path:
    """The path a new recording takes for ``requested`` (see the module's docstring);
    ``RecordingError`` for a fixed name that exists. The caller creates it exclusively."""
    path, made = recording_path(requested, device, datetime.now(UTC), suffix)
    if not made:
        if path.exists():
            raise RecordingError(taken_hint(path))
        return path
    return next(p for p in candidate_paths(path) if not p.exists())


def _open_new(
    requested: Path, device: str, header: SessionHeader, fsync_interval_s: float
) -> tuple[Path, SessionWriter]:
    """A writer on a new file; never one on an existing file."""
    while True:
        path = new_file(requested, device, ".scotti")
        try:
            # SessionWriter opens with "x": a file made since the check is refused, not
            # replaced (a made name then tries its next candidate).
            return path, SessionWriter(path, header, fsync_interval_s=fsync_interval_s)
        except SessionError as exc:
            if path.exists():
                continue
            raise RecordingError(str(exc)) from None


class Recorder:
    """Taps ``(t_ns, bytes)`` chunks into a new session file (source "recorded")."""

    def __init__(
        self, path: Path | str, *, device: str = "receiver", fsync_interval_s: float = 5.0
    ) -> None:
        self.requested = Path(path)
        self.records = 0
        self.bytes = 0
        self.events = 0  # event records (``mark``)
        self.failed: str | None = None  # why recording stopped early, if it did
        self.path, writer = _open_new(
            self.requested,
            device,
            SessionHeader(source="recorded", device=device),
            fsync_interval_s,
        )
        self._writer: SessionWriter | None = writer
        if self.path.parent == self.requested:
            log.info("recording to %s (in the directory %s)", self.path, self.requested)
        else:
            log.info("recording to %s", self.path)

    def tap(self, t_ns: int, data: bytes) -> None:
        """Append one chunk as it came off the port (garbage included)."""
        if self._writer is None:
            return
        try:
            self._writer.write_packet(t_ns, data)
        except (OSError, SessionError) as exc:
            self.failed = f"recording to {self.path} stopped: {exc}"
            log.error("%s", self.failed)
            self._close_quietly()
            return
        self.records += 1
        self.bytes += len(data)

    def mark(self, event: EventRecord) -> bool:
        """Write an event among the packets (``event/mark``); False when not recording."""
        if self._writer is None:
            return False
        try:
            self._writer.write(event)
        except (OSError, SessionError) as exc:
            self.failed = f"recording to {self.path} stopped: {exc}"
            log.error("%s", self.failed)
            self._close_quietly()
            return False
        self.events += 1
        return True

    @property
    def is_open(self) -> bool:
        """Still recording (not closed, not stopped by an error)."""
        return self._writer is not None

    def close(self) -> None:
        """Flush, fsync and close; safe to call twice."""
        if self._writer is not None:
            try:
                self._writer.close()
            except (OSError, SessionError) as exc:
                log.error("closing recording %s: %s", self.path, exc)
            self._writer = None

    def _close_quietly(self) -> None:
        writer, self._writer = self._writer, None
        if writer is not None:
            try:
                writer.close()
            except (OSError, SessionError):
                log.debug("closing a failed recording", exc_info=True)

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
