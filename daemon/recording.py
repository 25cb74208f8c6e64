"""``--record FILE``: the byte stream, before decoding, appended to a session file.

Each chunk read from the source becomes one packet record, written and
flushed on its own, so a daemon killed at any moment (kill -9, power cut)
leaves a file that reads back up to its last whole record. The OS is asked
to fsync every ``fsync_interval_s`` and on close.

A recording never stops the daemon: if the disk fills or the file goes away,
recording stops, the error is logged once and counted, the daemon goes on.
An existing file is never overwritten: the recorder takes the next free name
(``walk.scotti`` -> ``walk.1.scotti``) and says so in ``path``.
"""

from __future__ import annotations

import logging
from pathlib import Path

from scotti.daemon.errors import DaemonError
from scotti.firmware_protocol.errors import SessionError
from scotti.firmware_protocol.session import SessionHeader, SessionWriter

log = logging.getLogger(__name__)


class RecordingError(DaemonError):
    """The recording cannot start (directory missing, no permission); one line."""


def free_path(path: Path) -> Path:
    """``path`` itself, or ``stem.N.suffix`` with the first N that does not exist yet."""
    if not path.exists():
        return path
    n = 1
    while (candidate := path.with_name(f"{path.stem}.{n}{path.suffix}")).exists():
        n += 1
    return candidate


class Recorder:
    """Taps ``(t_ns, bytes)`` chunks into a new session file (source "recorded")."""

    def __init__(
        self, path: Path | str, *, device: str = "receiver", fsync_interval_s: float = 5.0
    ) -> None:
        self.requested = Path(path)
        self.path = free_path(self.requested)
        self.records = 0
        self.bytes = 0
        self.failed: str | None = None  # why recording stopped early, if it did
        try:
            self._writer: SessionWriter | None = SessionWriter(
                self.path,
                SessionHeader(source="recorded", device=device),
                fsync_interval_s=fsync_interval_s,
            )
        except SessionError as exc:
            raise RecordingError(str(exc)) from None
        if self.path != self.requested:
            log.warning("%s exists; recording to %s", self.requested, self.path)

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
