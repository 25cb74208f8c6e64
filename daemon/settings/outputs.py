"""Settings of the outputs beside MQTT (``[outputs]`` section, ``--record-mcap`` ...).

Kept apart from ``daemon.settings`` so that the outputs' options live with
the outputs; ``Settings.outputs`` holds one of these.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Self

from pydantic import BaseModel, ConfigDict, Field, SecretStr, model_validator

Port = Annotated[int, Field(ge=0, le=65535)]  # 0: any free port (the tests' choice)
# Well under systemd's default 1,024 descriptors, and more browsers than a lab opens.
DEFAULT_MAX_CONNECTIONS = 64


class OutputSettings(BaseModel):
    """Every output is off unless asked for; each works off the event loop (the network
    ones in a process of their own, docs/outputs.md)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    record_mcap: Path | None = None  # write the Foxglove channels into this MCAP file
    foxglove: Port | None = None  # serve the same channels over the Foxglove WebSocket protocol
    lsl: bool = False  # Lab Streaming Layer outlets: pose, actions, progress, pressure
    web: Port | None = None  # the browser live view on http://HOST:PORT/
    host: str = "127.0.0.1"  # where the Foxglove and web servers listen (0.0.0.0: everywhere)
    # Each of the Foxglove and web servers takes at most this many connections at a time.
    max_connections: int = Field(default=DEFAULT_MAX_CONNECTIONS, ge=1, le=100_000)
    # Host names let in beside IP literals, localhost names and ``host`` ("*": any).
    allowed_hosts: tuple[str, ...] = ()
    # Origins (browser pages) let in beside none and the server's own ("*": any).
    allowed_origins: tuple[str, ...] = ("https://app.foxglove.dev",)
    # A file whose first line is the token both servers then require (docs/outputs.md).
    token_file: Path | None = None
    token: SecretStr | None = Field(default=None, exclude=True)  # read from ``token_file``

    @property
    def any(self) -> bool:
        return bool(
            self.record_mcap or self.foxglove is not None or self.lsl or self.web is not None
        )

    @model_validator(mode="after")
    def _read_token_file(self) -> Self:
        if self.token is None and self.token_file is not None:
            try:
                lines = self.token_file.read_text(encoding="utf-8").splitlines()
            except OSError as exc:
                msg = f"cannot read token_file {self.token_file}: {exc.strerror}"
                raise ValueError(msg) from None
            token = lines[0].strip() if lines else ""
            if not token:
                msg = f"token_file {self.token_file}: the first line is empty"
                raise ValueError(msg)
            object.__setattr__(self, "token", SecretStr(token))
        return self
