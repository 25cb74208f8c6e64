"""One MQTT connection: a paho client driven by the asyncio loop, on paho's public API.

paho is written for a caller's own event loop: ``socket()`` to watch,
``loop_read`` / ``loop_write`` / ``loop_misc`` to call, ``want_write`` to say
whether bytes wait. Here the loop watches the socket for reading always;
after every call into paho what waits is written at once (``write``), and
the socket is watched for writing exactly while something is left
(level-triggered). Nothing depends on the order of paho's register/unregister
callbacks, which aiomqtt forwards through ``call_soon_threadsafe``: around a
reconnect those calls reach the loop after the socket they name was closed,
and the registration is lost (packets then sit in paho's queue until a
timeout; tests/test_daemon_publisher_reconnect.py shows it) or kept on a
socket with nothing to write (the loop then wakes for it without end).

Each connection is a fresh paho client, used only from the loop's thread once
its blocking connect (in a worker thread) has returned: a connection that
ended takes its unacknowledged messages with it, so a broker that never
acknowledges cannot make paho's resend queue grow; the publisher republishes
the retained state on every connect anyway.

Per-frame messages (QoS 0) do not go through ``paho.publish``, which writes
each message with a send of its own and makes an acknowledgement object for
each (at 32 pairs most of the publisher's cost): they come as whole PUBLISH
packets (``packets``), are queued, and the frames queued since the last
write leave in one send. paho's own packets (CONNECT, retained publishes,
PUBACK, PINGREQ, DISCONNECT) go through its queue as before; paho is kept
from writing by itself (an ``on_socket_register_write`` callback makes it
only queue), so all bytes leave from ``write``, in the order they were queued
(what waits is tried at once: only a full socket leaves anything queued),
and nothing is ever written into a packet a full socket cut short.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import ssl
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Final

import paho.mqtt.client as paho
from paho.mqtt.enums import CallbackAPIVersion, MQTTErrorCode
from paho.mqtt.properties import Properties
from paho.mqtt.reasoncodes import ReasonCode
from paho.mqtt.subscribeoptions import SubscribeOptions
from scotti.daemon.errors import DaemonError
from scotti.daemon.settings.mqtt import MqttSettings

if TYPE_CHECKING:
    from paho.mqtt.client import SocketLike

MISC_EVERY_S: Final = 1.0  # paho's keepalive bookkeeping (PINGREQ, a silent broker)
CONNACK_TIMEOUT_S: Final = 5.0  # from the TCP (and TLS) connect to the broker's CONNACK
CLOSE_TIMEOUT_S: Final = 2.0  # a graceful DISCONNECT, then the socket is closed anyway


class BrokerLostError(DaemonError):
    """The connection could not be made or has ended; the message says why, in one line."""


class Connection:
    """Connect, publish (each publish a future: written at QoS 0, acknowledged at
    QoS 1), subscribe, close. ``lost`` resolves, with the reason, when it ends."""

    def __init__(
        self,
        settings: MqttSettings,
        will: tuple[str, bytes, Properties | None],
        on_message: Callable[[paho.MQTTMessage], None],
        logger: logging.Logger,
        tls: ssl.SSLContext | None = None,
    ) -> None:
        """``tls``: the context for ``mqtts://`` (``settings.tls_context()``, made once)."""
        self.settings = settings
        self.v5 = settings.protocol == "5"
        self._loop = asyncio.get_running_loop()
        self._on_message = on_message
        self._fd: int | None = None  # the socket the loop watches, while it does
        self._writing = False  # ... for writability too
        self._sock: SocketLike | None = None  # paho's socket, while connected
        self._frames = bytearray()  # QoS 0 packets queued, not yet written
        self._paho_cut = False  # paho's queue was left by a full socket: it goes first
        self._drained: asyncio.Future[None] | None = None  # while frames wait for room
        self._misc: asyncio.Task[None] | None = None
        self._connack: asyncio.Future[ReasonCode] = self._loop.create_future()
        self.lost: asyncio.Future[str] = self._loop.create_future()
        # mid -> its publish: (future, when handed to paho); QoS 0 ones until written.
        self._pending: dict[int, tuple[asyncio.Future[ReasonCode | None], float, int]] = {}
        self._subscribes: dict[int, asyncio.Future[list[ReasonCode]]] = {}

        client = paho.Client(
            callback_api_version=CallbackAPIVersion.VERSION2,
            client_id=settings.client_id or f"scotti-daemon-{settings.device_id}",
            protocol=paho.MQTTv5 if self.v5 else paho.MQTTv311,
            reconnect_on_failure=False,
        )
        client.enable_logger(logger)
        if settings.username is not None:
            password = settings.password.get_secret_value() if settings.password else None
            client.username_pw_set(settings.username, password)
        if tls is not None:
            client.tls_set_context(tls)
        topic, payload, props = will
        client.will_set(topic, payload, qos=1, retain=True, properties=props)
        client.on_connect = self._connected
        client.on_disconnect = self._on_disconnect
        client.on_publish = self._published
        client.on_subscribe = self._subscribed
        client.on_message = lambda _c, _u, message: self._on_message(message)
        client.on_socket_close = lambda _c, _u, _s: self._detach()
        # Present, paho only queues its packets; ``write`` writes them.
        client.on_socket_register_write = lambda _c, _u, _s: None
        self._paho = client

    # --- life --------------------------------------------------------------------------
    async def open(self) -> None:
        """Connect and wait for the CONNACK; ``BrokerLostError`` if refused or unanswered."""
        try:
            # Blocking (name lookup, TCP and TLS handshakes): in a worker thread. paho
            # writes the CONNECT there too; nothing else touches the client until then.
            await self._loop.run_in_executor(None, self._blocking_connect)
        except (OSError, ssl.SSLError, ValueError) as exc:
            raise BrokerLostError(str(exc) or type(exc).__name__) from None
        sock = self._paho.socket()
        if sock is None:  # closed already (paho logged why)
            msg = "connection lost"
            raise BrokerLostError(msg)
        self._sock = sock
        self._fd = sock.fileno()
        self._loop.add_reader(self._fd, self._readable)
        self.write()  # the CONNECT
        self._misc = self._loop.create_task(self._misc_loop(), name="mqtt-keepalive")
        waiting: set[asyncio.Future[Any]] = {self._connack, self.lost}
        try:
            done, _ = await asyncio.wait(
                waiting,
                timeout=CONNACK_TIMEOUT_S,
                return_when=asyncio.FIRST_COMPLETED,
            )
        except asyncio.CancelledError:
            self.abort()
            raise
        if self._connack in done:
            code = self._connack.result()
            if not code.is_failure:
                return
            self.abort()
            msg = f"[code:{code.value}] {code}"
            raise BrokerLostError(msg)
        self.abort()
        msg = self.lost.result() if self.lost in done else "no answer from the broker (timed out)"
        raise BrokerLostError(msg)

    def _blocking_connect(self) -> None:
        # MQTT v5: a clean start each time (nothing of an old session is wanted: the
        # retained state is republished); 3.1.1: the client's clean session.
        start = True if self.v5 else paho.MQTT_CLEAN_START_FIRST_ONLY
        self._paho.connect(
            self.settings.host, self.settings.port, self.settings.keepalive_s, clean_start=start
        )

    async def close(self) -> None:
        """A graceful DISCONNECT (the broker drops the last will), then the socket."""
        if not self.lost.done() and self._fd is not None:
            self._paho.disconnect()
            self.write()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(asyncio.shield(self.lost), CLOSE_TIMEOUT_S)
        self.abort()

    def abort(self) -> None:
        """Drop the connection without DISCONNECT: the broker publishes the last will."""
        sock = self._paho.socket()
        self._detach()
        if sock is not None:
            sock.close()
        self._end("connection closed")

    def _end(self, reason: str) -> None:
        if not self.lost.done():
            self.lost.set_result(reason)
        for future, _at, _qos in self._pending.values():
            future.cancel()
        self._pending.clear()
        for sub in self._subscribes.values():
            sub.cancel()
        self._subscribes.clear()
        self._frames.clear()
        if self._drained is not None:
            self._drained.cancel()
            self._drained = None
        if self._misc is not None:
            self._misc.cancel()

    # --- the loop's side: read, write exactly while paho wants to, keepalive ---------------
    def _readable(self) -> None:
        sock = self._paho.socket()
        while True:
            rc = self._paho.loop_read()
            # TLS: a read may leave decrypted bytes in the SSL object, which the
            # selector does not see; read them now.
            if rc != MQTTErrorCode.MQTT_ERR_SUCCESS or not isinstance(sock, ssl.SSLSocket):
                break
            if sock.fileno() < 0 or not sock.pending():
                break
        self._after(rc)

    def _writable(self) -> None:
        self.write()

    async def _misc_loop(self) -> None:
        while True:
            await asyncio.sleep(MISC_EVERY_S)
            self._after(self._paho.loop_misc())

    def _after(self, rc: MQTTErrorCode) -> None:
        if rc != MQTTErrorCode.MQTT_ERR_SUCCESS:
            self._lose(_lost_reason(rc))
            return
        self.write()

    def _lose(self, reason: str) -> None:
        self._detach()
        self._end(reason)

    def write(self) -> None:
        """Write what waits, as far as the socket takes it: first what a full socket cut
        short, then the frames, then paho's queue; watch for writability while some is
        left. One send for all the frames queued since the last write."""
        sock = self._sock
        if self._fd is None or sock is None:
            return
        paho = self._paho
        while True:
            if self._paho_cut or (not self._frames and paho.want_write()):
                rc = paho.loop_write()
                if rc != MQTTErrorCode.MQTT_ERR_SUCCESS:
                    self._lose(_lost_reason(rc))
                    return
                self._paho_cut = paho.want_write()
                if self._paho_cut or self._fd is None:  # full, or a DISCONNECT closed it
                    break
            if self._frames:
                try:
                    sent = sock.send(self._frames)
                except (BlockingIOError, ssl.SSLWantWriteError, ssl.SSLWantReadError):
                    break
                except OSError as exc:
                    self._lose(f"connection lost ({exc.strerror or exc})")
                    return
                del self._frames[:sent]
                if self._frames:
                    break
                if self._drained is not None:
                    self._drained.set_result(None)
                    self._drained = None
            if not paho.want_write():
                break
        self._watch_writable(bool(self._frames) or paho.want_write())

    def _watch_writable(self, want: bool) -> None:
        if want == self._writing or self._fd is None:
            return
        if want:
            self._loop.add_writer(self._fd, self._writable)
        else:
            self._loop.remove_writer(self._fd)
        self._writing = want

    def _detach(self) -> None:
        """Stop watching the socket (paho is about to close it, or has)."""
        if self._fd is None:
            return
        self._loop.remove_reader(self._fd)
        self._loop.remove_writer(self._fd)
        self._fd, self._writing, self._sock = None, False, None

    # --- publishing ------------------------------------------------------------------------
    def queue_frame(self, packet: bytes) -> None:
        """Queue one QoS 0 PUBLISH packet (``qos0.packet``); ``write`` sends it."""
        if self.lost.done():
            raise BrokerLostError(self.lost.result())
        self._frames += packet

    @property
    def frames_waiting(self) -> int:
        """Bytes of queued frames the socket has not taken yet."""
        return len(self._frames)

    def frames_written(self) -> asyncio.Future[None]:
        """Done once the queued frames are all written (cancelled if the connection ends)."""
        future = self._drained or self._loop.create_future()
        if self._frames:
            self._drained = future
        else:
            future.set_result(None)
        return future

    def publish(
        self, topic: str, payload: bytes, qos: int, retain: bool, props: Properties | None
    ) -> asyncio.Future[ReasonCode | None]:
        """Hand one message to paho; the future is done once it is written (QoS 0, None)
        or acknowledged (QoS 1: the PUBACK's reason code, a refusal included)."""
        if self.lost.done():
            raise BrokerLostError(self.lost.result())
        info = self._paho.publish(topic, payload, qos=qos, retain=retain, properties=props)
        self.write()
        if info.rc != MQTTErrorCode.MQTT_ERR_SUCCESS:
            raise BrokerLostError(_lost_reason(info.rc))
        future: asyncio.Future[ReasonCode | None] = self._loop.create_future()
        if qos == 0 and info.is_published():  # written at once, the usual case
            future.set_result(None)
        else:
            self._pending[info.mid] = (future, self._loop.time(), qos)
        return future

    @property
    def unacknowledged(self) -> int:
        """QoS 1 publishes handed over and not yet acknowledged."""
        return sum(1 for _f, _at, qos in self._pending.values() if qos > 0)

    async def subscribe(self, topic: str) -> ReasonCode:
        """Subscribe at QoS 1: under v5 without our own publishes (no local) and with
        the retain flag as published. The SUBACK's reason code (a failure: refused)."""
        if self.v5:
            options = SubscribeOptions(qos=1, noLocal=True, retainAsPublished=True)
            rc, mid = self._paho.subscribe(topic, options=options)
        else:
            rc, mid = self._paho.subscribe(topic, qos=1)
        self.write()
        if rc != MQTTErrorCode.MQTT_ERR_SUCCESS or mid is None:
            raise BrokerLostError(_lost_reason(rc))
        future: asyncio.Future[list[ReasonCode]] = self._loop.create_future()
        self._subscribes[mid] = future
        (code,) = await future
        return code

    # --- paho's callbacks (the loop's thread, from loop_read/loop_write/loop_misc) ---------
    def _connected(self, _c: Any, _u: Any, _flags: Any, reason: ReasonCode, _p: Any) -> None:
        if not self._connack.done():
            self._connack.set_result(reason)

    def _on_disconnect(self, *_args: Any) -> None:
        self._detach()
        self._end("connection lost")

    def _published(self, _c: Any, _u: Any, mid: int, reason: ReasonCode, _p: Any) -> None:
        pending = self._pending.pop(mid, None)
        if pending is not None and not pending[0].done():
            pending[0].set_result(reason if pending[2] > 0 else None)

    def _subscribed(self, _c: Any, _u: Any, mid: int, codes: list[ReasonCode], _p: Any) -> None:
        future = self._subscribes.pop(mid, None)
        if future is not None and not future.done():
            future.set_result(codes)


def _lost_reason(rc: MQTTErrorCode) -> str:
    if rc in (MQTTErrorCode.MQTT_ERR_NO_CONN, MQTTErrorCode.MQTT_ERR_CONN_LOST):
        return "connection lost"
    return paho.error_string(rc)
