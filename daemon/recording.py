"""``--record FILE``: the byte stream, before decoding, appended to a session file.

Each chunk read from the source becomes one packet record, written and
flushed on its own, so a daemon killed at any moment (kill -9, power cut)
leaves a file that reads back up to its last whole record. The OS is asked
to fsync every ``fsync_interval_s`` and on close.

A recording never stops the daemon: if the disk fills or the file goes away,
recording stops, the error is logged once and counted, the daemon goes on.
An existing file is never overwritten: the recorder takes a new name beside it,
stamped with the UTC start time (``walk.scotti`` -> ``walk.20261121T135630.scotti``,
then ``walk.20261121T135630.1.scotti``), logs it and says so in ``path``.
``--record`` naming a directory records into a new file inside it, named after
the device and the UTC start time (``lab1-20261121T135630.scotti``).
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from datetime import UTC, datetime
from pathlib import Path

from scotti.daemon.errors import DaemonError
from scotti.firmware_protocol.errors import SessionError
from scotti.firmware_protocol.session import SessionHeader, SessionWriter

log = logging.getLogger(__name__)


class RecordingError(DaemonError):
    """The recording cannot start (directory missing, no permission); one line."""


def candidate_paths(path: Path, now: datetime) -> Iterator[Path]:
    """``path``, then ``stem.<UTC yyyymmddThhmmss>suffix``, then that with ``.1``, ``.2``..."""
    yield path
    stamp = now.astimezone(UTC).strftime("%Y%m%dT%H%M%S")
    yield path.with_name(f"{path.stem}.{stamp}{path.suffix}")
    n = 1
    while True:
        yield path.with_name(f"{path.stem}.{stamp}.{n}{path.suffix}")
        n += 1


def _open_new(
    requested: Path, header: SessionHeader, fsync_interval_s: float
) -> tuple[Path, SessionWriter]:
    """A writer on the first free candidate name; never one on an existing file."""
    for path in candidate_paths(requested, datetime.now(UTC)):
        if path.exists():
            continue
        try:
            # SessionWriter opens with "x": a file made since the check is refused, not
            # replaced, and the next name is tried.
            return path, SessionWriter(path, header, fsync_interval_s=fsync_interval_s)
        except SessionError as exc:
            if path.exists():
                continue
            raise RecordingError(str(exc)) from None
    raise AssertionError("unreachable: candidate_paths never ends")


def file_for(requested: Path, device: str, now: datetime) -> Path:
    """``requested`` itself, or a file named after ``device`` and ``now`` inside it when it
    is a directory (never a sibling file next to the directory)."""
    if requested.is_dir():
        stamp = now.astimezone(UTC).strftime("%Y%m%dT%H%M%S")
        return requested / f"{device}-{stamp}.scotti"
    return requested


class Recorder:
    """Taps ``(t_ns, bytes)`` chunks into a new session file (source "recorded")."""

    def __init__(
        self, path: Path | str, *, device: str = "receiver", fsync_interval_s: float = 5.0
    ) -> None:
        self.requested = Path(path)
        self.records = 0
        self.bytes = 0
        self.failed: str | None = None  # why recording stopped early, if it did
        self.path, writer = _open_new(
            file_for(self.requested, device, datetime.now(UTC)),
            SessionHeader(source="recorded", device=device),
            fsync_interval_s,
        )
        self._writer: SessionWriter | None = writer
        if self.path.parent == self.requested:
            log.info("recording to %s (in the directory %s)", self.path, self.requested)
        elif self.path != self.requested:
            log.info("recording to %s (%s exists: never overwritten)", self.path, self.requested)
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
