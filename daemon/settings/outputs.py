"""Settings of the outputs beside MQTT (``[outputs]`` section, ``--record-mcap`` ...).

Kept apart from ``daemon.settings`` so that the outputs' options live with
the outputs; ``Settings.outputs`` holds one of these.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

Port = Annotated[int, Field(ge=0, le=65535)]  # 0: any free port (the tests' choice)


class OutputSettings(BaseModel):
    """Every output is off unless asked for; none of them slows the MQTT path."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    record_mcap: Path | None = None  # write the Foxglove channels into this MCAP file
    foxglove: Port | None = None  # serve the same channels over the Foxglove WebSocket protocol
    lsl: bool = False  # Lab Streaming Layer outlets: pose, actions, progress, pressure
    web: Port | None = None  # the browser live view on http://HOST:PORT/
    host: str = "127.0.0.1"  # where the Foxglove and web servers listen (0.0.0.0: everywhere)

    @property
    def any(self) -> bool:
        return bool(
            self.record_mcap or self.foxglove is not None or self.lsl or self.web is not None
        )
