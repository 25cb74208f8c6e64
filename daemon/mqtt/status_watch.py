"""The daemon's own retained ``status``, watched: another client's is replaced.

The publisher subscribes to its own status topic on every connection. The
broker then hands back the retained status just published: if it does not
(mosquitto grants the subscription and filters what its ACL does not let us
read), the watch is blind and the log says so. A status that differs from the
one the broker last acknowledged for us is another client's (same device id
twice, or forged): the publisher publishes its own again, at most once every
``RESTORE_EVERY_S``. Under MQTT 3.1.1 (no "no local") our own publishes come
back too; they are recognised and let pass.
"""

from __future__ import annotations

import asyncio
import collections
import time
from collections.abc import Awaitable, Callable
from typing import Final, TypeVar

import paho.mqtt.client as paho
from paho.mqtt.reasoncodes import ReasonCode
from scotti.daemon.mqtt.connection import Connection
from scotti.daemon.settings.mqtt import MqttSettings

T = TypeVar("T")
MAX_ECHOES: Final = 16  # our own status changes that may still come back (MQTT 3.1.1)
RESTORE_EVERY_S: Final = 1.0  # a status of another client's is replaced at most this often


class StatusWatch:
    """What the broker holds on our status topic, against what we last published."""

    def __init__(
        self, settings: MqttSettings, wake: Callable[[], None], say: Callable[..., None]
    ) -> None:
        """``wake``: the publisher has work (a status to restore); ``say(what, fmt,
        *args)``: a WARNING at most once per burst of the same ``what``."""
        self.settings = settings
        self.topic = settings.topic("status")
        self.sent: bytes | None = None  # the status the broker last acknowledged
        self.restore_due = False  # another client's status seen: publish ours again
        self._wake = wake
        self._say = say
        self._echoes: collections.deque[bytes] = collections.deque(maxlen=MAX_ECHOES)
        self._watched = False  # our status topic delivers to us (this connection)
        self._restored_at = -RESTORE_EVERY_S

    def published(self, data: bytes, v5: bool) -> None:
        """Our status ``data`` was acknowledged by the broker."""
        self.sent = data
        if not v5:  # 3.1.1 has no "no local": our own publish comes back
            self._echoes.append(data)

    def taken(self) -> None:
        """What the broker holds now is ours (a status of ours was just published)."""
        self.restore_due = False

    async def watch(
        self, conn: Connection, wait: Callable[[Awaitable[ReasonCode]], Awaitable[ReasonCode]]
    ) -> None:
        """Subscribe on ``conn`` (``wait`` awaits the SUBACK, with the ack timeout). From
        now on what the broker holds is what was just published, so anything different
        that comes is another client's."""
        self._echoes.clear()
        self._watched = False
        code = await wait(conn.subscribe(self.topic))
        if code.is_failure:
            self._say_unwatched(str(code))
        elif self.sent is not None:

            def check() -> None:
                if not self._watched and not conn.lost.done():
                    self._say_unwatched("the retained status did not come back")

            asyncio.get_running_loop().call_later(self.settings.ack_timeout_s, check)

    def _say_unwatched(self, why: str) -> None:
        self._say(
            "unwatched",
            "cannot read %s on broker %s (%s): a status another client publishes there is "
            "not replaced; let the daemon read its own status topic (its ACL)",
            self.topic,
            self.settings.broker,
            why,
        )

    def seen(self, message: paho.MQTTMessage) -> None:
        """A message on our status topic (paho's callback, in the loop's thread)."""
        self._watched = True
        payload = bytes(message.payload)
        if self._echoes and payload == self._echoes[0]:
            self._echoes.popleft()  # our own, back from the broker (MQTT 3.1.1)
            return
        if self.sent is None or payload == self.sent:
            return
        self.restore_due = True
        self._wake()

    def take_restore(self) -> bytes | None:
        """Our status to publish again over another client's, or None: not yet (at most
        once every RESTORE_EVERY_S; the publisher is woken when it is time) or nothing
        of ours was ever acknowledged."""
        wait_s = self._restored_at + RESTORE_EVERY_S - time.monotonic()
        if wait_s > 0:
            asyncio.get_running_loop().call_later(wait_s, self._wake)
            return None
        if self.sent is None:
            return None
        self.restore_due = False
        self._restored_at = time.monotonic()
        return self.sent
