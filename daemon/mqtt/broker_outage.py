"""The broker's outages as the log says them, and why a connection failed, in one line.

A broker that goes away, restarts or refuses (bad password, unknown CA) is
one WARNING line with the reason when the outage starts, said again every
``outage_warning_s`` while it stays away (a daemon that waits in silence for a
broker nobody started looks like one that works); the retries in between
only at debug. Never an ERROR, never a traceback.
"""

from __future__ import annotations

import logging
import time
from typing import Final

import aiomqtt
import paho.mqtt.client as paho
from scotti.daemon.settings.mqtt import MqttSettings

log = logging.getLogger("scotti.daemon.mqtt.publisher")  # where operators look for it

_LOST: Final = (paho.MQTT_ERR_NO_CONN, paho.MQTT_ERR_CONN_LOST)


class Outage:
    """The current outage, if any: when it started, when the log last said it."""

    def __init__(self, settings: MqttSettings) -> None:
        self.settings = settings
        self.down_since: float | None = None  # monotonic start of the current outage
        self._warned_at = 0.0  # the last outage WARNING

    def failed(self, detail: str) -> bool:
        """A connection failed or ended (``detail``: why); True when an outage starts."""
        now = time.monotonic()
        broker, hint = self.settings.broker, _hint(detail, self.settings.port)
        if self.down_since is None:
            self.down_since = self._warned_at = now
            log.warning("broker %s: %s; retrying with backoff%s", broker, detail, hint)
            return True
        if now - self._warned_at >= self.settings.outage_warning_s:
            self._warned_at = now
            log.warning(
                "broker %s: still unreachable after %.0f s (%s); retrying every %g s at most%s",
                broker,
                now - self.down_since,
                detail,
                self.settings.reconnect_max_s,
                hint,
            )
        else:
            log.debug("broker %s: %s; retrying with backoff", broker, detail)
        return False

    def end(self) -> float:
        """The broker is back (or the publisher stops): the outage's seconds, 0 if none."""
        if self.down_since is None:
            return 0.0
        took = time.monotonic() - self.down_since
        self.down_since = None
        return took

    @property
    def current_s(self) -> float:
        """Seconds of the outage going on now, 0 when there is none."""
        return time.monotonic() - self.down_since if self.down_since is not None else 0.0


def _hint(detail: str, port: int) -> str:
    """What to do about a refused connection: nothing listens at that address."""
    if "refused" not in detail.lower():
        return ""
    return (
        "; is a broker running? (apt install mosquitto, or "
        f"python -m scotti.daemon.tools.local_broker --port {port})"
    )


def explain(exc: aiomqtt.MqttError) -> str:
    """One line saying why the broker connection failed or ended."""
    if isinstance(exc, aiomqtt.MqttCodeError) and exc.rc in _LOST:
        return "connection lost"
    text = str(exc) or type(exc).__name__
    if text == "Operation timed out":
        return "no answer from the broker (timed out)"
    return text.removesuffix(".")
