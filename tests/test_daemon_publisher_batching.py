"""Frames written in batches: order kept around status changes, a full socket waited on.

The publisher takes every queued prediction at once (up to the next status
change) and writes their messages with one send. Against a real mosquitto: a
status change lands between the predictions submitted before and after it,
and every message validates against its schema. Through a proxy that stops
reading (a broker that takes the connection and then no bytes): the socket
fills, the publisher waits for it at most ``ack_timeout_s``, then drops the
connection, counts the predictions lost in it and reconnects.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import threading
import time
from collections.abc import Iterator

import pytest
from scotti.daemon.mqtt.publisher import Publisher
from scotti.daemon.mqtt.schemas import TOPICS, Status
from scotti.daemon.settings import MqttSettings
from scotti.daemon.tools.local_broker import Mosquitto

from tests.support.broker import collect
from tests.support.publishing import batch, info, status
from tests.test_daemon_publisher import running, until

pytestmark = pytest.mark.mosquitto


def test_a_status_change_lands_between_the_predictions_around_it(mosquitto: Mosquitto) -> None:
    mqtt = MqttSettings(broker=mosquitto.url, device_id="dev1", pressure=True)
    with collect(mosquitto, "scotti/dev1/#") as got:

        async def body(pub: Publisher) -> None:
            await until(lambda: pub.state == "connected")
            await asyncio.sleep(0.2)  # the retained state out of the way
            for seq in range(5):  # queued together, sent in one go
                pub.submit(batch(seq))
            pub.set_status(status("degraded"))
            for seq in range(5, 10):
                pub.submit(batch(seq))
            await until(lambda: pub.stats.published == 10)

        running(lambda: Publisher(mqtt, info(), will=status("offline")), body)
        got.wait_for(lambda m: len([x for x in m if x.topic.endswith("progress")]) == 10, 5)
    order = []
    for m in got.snapshot():
        name = m.topic.rsplit("/", 1)[1]
        payload = TOPICS[name].model_validate_json(m.payload)  # every message valid
        if name == "progress":
            order.append(payload.seq)  # type: ignore[attr-defined]
        elif name == "status" and isinstance(payload, Status) and payload.state == "degraded":
            order.append("degraded")
    assert order == [0, 1, 2, 3, 4, "degraded", 5, 6, 7, 8, 9]
    for name in ("pose", "action", "progress", "pressure"):
        assert len(got.snapshot(name)) == 10, name


class StallingProxy:
    """TCP to mosquitto and back; ``stall()`` stops reading from the clients connected
    now (new connections flow). A small receive buffer, so a stalled socket fills soon."""

    def __init__(self, upstream: tuple[str, int]) -> None:
        self.upstream = upstream
        self.listener = socket.socket()
        self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        self.listener.bind(("127.0.0.1", 0))
        self.listener.listen()
        self.url = f"mqtt://127.0.0.1:{self.listener.getsockname()[1]}"
        self._stalls: list[threading.Event] = []
        self._sockets: list[socket.socket] = []
        threading.Thread(target=self._accept, daemon=True).start()

    def stall(self) -> None:
        for stalled in self._stalls:
            stalled.set()

    def close(self) -> None:
        self.listener.close()
        for sock in self._sockets:
            sock.close()

    def _accept(self) -> None:
        while True:
            try:
                client, _ = self.listener.accept()
            except OSError:  # closed
                return
            up = socket.create_connection(self.upstream)
            self._sockets += [client, up]
            stalled = threading.Event()
            self._stalls.append(stalled)
            threading.Thread(target=_forward, args=(client, up, stalled), daemon=True).start()
            threading.Thread(target=_forward, args=(up, client, None), daemon=True).start()


def _forward(src: socket.socket, dst: socket.socket, stalled: threading.Event | None) -> None:
    with contextlib.suppress(OSError):
        while not (stalled is not None and stalled.is_set()):
            data = src.recv(65536)
            if not data:
                break
            dst.sendall(data)
    if stalled is not None and stalled.is_set():
        return  # read nothing more: the client's bytes pile up in its socket
    for sock in (src, dst):
        with contextlib.suppress(OSError):
            sock.shutdown(socket.SHUT_RDWR)


@contextlib.contextmanager
def stalling_proxy(broker: Mosquitto) -> Iterator[StallingProxy]:
    proxy = StallingProxy((broker.host, broker.port))
    try:
        yield proxy
    finally:
        proxy.close()


def test_a_socket_that_stays_full_is_a_broker_that_does_not_acknowledge(
    mosquitto: Mosquitto,
) -> None:
    with stalling_proxy(mosquitto) as proxy:
        mqtt = MqttSettings(
            broker=proxy.url,
            device_id="dev1",
            pressure=True,
            pressure_downsample=1,  # big messages: the socket fills sooner
            ack_timeout_s=1,
            reconnect_max_s=0.5,
        )
        stalled_for: list[float] = []

        async def body(pub: Publisher) -> None:
            await until(lambda: pub.state == "connected")
            proxy.stall()
            started, seq = time.monotonic(), 0
            while pub.stats.not_acknowledging == 0:
                assert time.monotonic() - started < 30, "the full socket was never noticed"
                pub.submit(batch(seq))
                seq += 1
                await asyncio.sleep(0.001)
            stalled_for.append(time.monotonic() - started)
            await until(lambda: pub.stats.connects == 2)  # a fresh connection flows
            published = pub.stats.published
            pub.submit(batch(seq))
            await until(lambda: pub.stats.published == published + 1)

        pub = running(lambda: Publisher(mqtt, info(), will=status("offline")), body, timeout=60)
    assert pub.stats.not_acknowledging == 1
    assert pub.stats.outages == 1
    assert pub.stats.last_error.startswith("not acknowledging: no answer to a publish within 1 s")
    assert pub.stats.dropped_error >= 1  # the predictions in the write that never finished
    assert pub.stats.published > 0
    assert stalled_for[0] >= 1.0  # it waited its ack_timeout_s first
