"""Where the bytes come from: ``[source]`` (one insole pair) or ``[[devices]]`` (several).

``Settings`` holds one ``SourceSettings`` or a tuple of ``DeviceSettings``;
each names exactly one of a serial port, a session file to replay or a
scene to simulate.
"""

from __future__ import annotations

from pathlib import Path
from typing import Final, Literal

from pydantic import BaseModel, ConfigDict, field_validator, model_validator
from scotti.daemon.input.speed import Speed, parse_speed
from scotti.daemon.settings.checks import check_device_id, is_file

_KINDS: Final = ("port", "replay", "simulate")  # the fields of which one names the source


class SourceSettings(BaseModel):
    """Where the bytes come from: exactly one of port, replay, simulate."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    port: str | None = None  # serial device, e.g. /dev/scotti-receiver
    replay: Path | None = None  # session file fed back through the live path
    simulate: str | None = None  # scene name (sim/scenes/NAME.toml) or a scene TOML path
    speed: Speed = 1.0  # replay / simulate rate: 1 = real time, N times, or max
    once: bool = False  # simulate: play the scene once and end (default: in a loop)

    @field_validator("speed", mode="before")
    @classmethod
    def _speed(cls, v: object) -> Speed:
        return parse_speed(v)

    @model_validator(mode="after")
    def _exactly_one(self) -> SourceSettings:
        given = self._given()
        if not given:
            msg = "no source: set --port (source.port), --replay, --simulate or [[devices]]"
            raise ValueError(msg)
        if len(given) > 1:
            msg = f"give only one source, got {' and '.join(given)}"
            raise ValueError(msg)
        problem = self._replay_problem() or self._once_problem()
        if problem:
            raise ValueError(problem)
        return self

    def _given(self) -> list[str]:
        """The source fields that are set, in the order of ``_KINDS``."""
        return [n for n in _KINDS if getattr(self, n) is not None]

    def _once_problem(self) -> str | None:
        if not self.once or self.simulate is not None:
            return None
        why = "a replay plays once already" if self.replay else "a port has no end"
        return f"once: goes with --simulate ({why})"

    def _replay_problem(self) -> str | None:
        """Why ``replay`` cannot be replayed, found from its head alone (the whole file
        is checked when the replay starts: ``sources.check_replay``); None when it may be."""
        if self.replay is None:
            return None
        if not is_file(self.replay):
            return f"replay file not found: {self.replay}"
        return replay_head_problem(self.replay)

    @property
    def kind(self) -> Literal["port", "replay", "simulate"]:
        return "port" if self.port else "replay" if self.replay else "simulate"


class DeviceSettings(SourceSettings):
    """One insole pair in ``[[devices]]``: its id (the topic level) and its source.

    A receiver is best named by its ``/dev/serial/by-id/...`` path: it stays the
    same across reboots and replugging, whichever USB port it is in.
    """

    id: str  # scotti/<id>/...: unique in the daemon, a valid MQTT topic level
    record: Path | None = None  # this device's recording (default: the top-level record)

    @field_validator("id")
    @classmethod
    def _id(cls, v: str) -> str:
        return check_device_id(v)

    @model_validator(mode="after")
    def _exactly_one(self) -> DeviceSettings:
        given = self._given()
        if len(given) != 1:
            what = f"got {' and '.join(given)}" if given else "got none"
            msg = f"device {self.id!r}: give exactly one of port, replay, simulate ({what})"
            raise ValueError(msg)
        problem = self._replay_problem() or self._once_problem()
        if problem:
            msg = f"device {self.id!r}: {problem}"
            raise ValueError(msg)
        return self


def replay_head_problem(path: Path) -> str | None:
    """Why ``path`` is not a session file to replay, from its first bytes: empty, not a
    session, cut before its header (one line naming the file); None when its head is one."""
    from scotti.firmware_protocol.errors import SessionError
    from scotti.firmware_protocol.session import SessionReader

    try:
        if path.stat().st_size == 0:
            return f"replay: {path} is empty (0 bytes), not a session file"
        SessionReader(path).close()
    except SessionError as exc:
        return f"replay: {exc}"
    except OSError as exc:
        return f"replay: cannot read {path}: {exc.strerror}"
    return None
