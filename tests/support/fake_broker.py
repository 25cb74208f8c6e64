"""A broker that answers CONNACK (and SUBACK, PINGRESP) but never acknowledges a publish.

Just enough MQTT (3.1.1 and 5) over asyncio TCP to let a client connect and
then swallow every PUBLISH: what a wedged or hostile broker looks like to the
daemon. Runs its own event loop in a thread; ``connects`` counts CONNECTs and
``publishes`` the PUBLISH packets it swallowed.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Final

CONNECT: Final = 1  # MQTT control packet types (the high nibble of the first byte)
PUBLISH: Final = 3
SUBSCRIBE: Final = 8
PINGREQ: Final = 12
DISCONNECT: Final = 14


@dataclass
class SilentBroker:
    host: str = "127.0.0.1"
    port: int = 0
    connects: int = 0
    publishes: int = 0
    _loop: asyncio.AbstractEventLoop = field(default_factory=asyncio.new_event_loop)
    _server: asyncio.Server | None = None
    _writers: set[asyncio.StreamWriter] = field(default_factory=set)

    @property
    def url(self) -> str:
        return f"mqtt://{self.host}:{self.port}"

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self._writers.add(writer)
        v5 = False
        try:
            while True:
                first = (await reader.readexactly(1))[0]
                length, shift = 0, 0
                while True:  # remaining length: 7 bits a byte, high bit = more
                    byte = (await reader.readexactly(1))[0]
                    length |= (byte & 0x7F) << shift
                    shift += 7
                    if not byte & 0x80:
                        break
                body = await reader.readexactly(length)
                kind = first >> 4
                if kind == CONNECT:
                    self.connects += 1
                    v5 = body[6] == 5  # [len:2]["MQTT"][level:1]
                    writer.write(b"\x20\x03\x00\x00\x00" if v5 else b"\x20\x02\x00\x00")
                elif kind == PUBLISH:
                    self.publishes += 1  # swallowed: no PUBACK, ever
                elif kind == SUBSCRIBE:
                    mid = body[:2]
                    props = 1 + body[2] if v5 else 0  # a short property length (< 128)
                    filters = body[2 + props :]
                    granted = []
                    while filters:  # [len:2][filter][options:1] ...
                        n = int.from_bytes(filters[:2], "big")
                        granted.append(filters[2 + n] & 0x03)
                        filters = filters[3 + n :]
                    payload = mid + (b"\x00" if v5 else b"") + bytes(granted)
                    writer.write(bytes([0x90, len(payload)]) + payload)
                elif kind == PINGREQ:
                    writer.write(b"\xd0\x00")
                elif kind == DISCONNECT:
                    return
                await writer.drain()
        except (asyncio.IncompleteReadError, ConnectionError):
            return
        finally:
            self._writers.discard(writer)
            writer.close()

    def _thread_main(self, ready: threading.Event) -> None:
        asyncio.set_event_loop(self._loop)

        async def start() -> None:
            self._server = await asyncio.start_server(self._serve, self.host, self.port)
            sock: socket.socket = self._server.sockets[0]
            self.port = sock.getsockname()[1]
            ready.set()

        self._loop.run_until_complete(start())
        self._loop.run_forever()
        self._loop.close()

    def _shutdown(self) -> None:
        assert self._server is not None
        self._server.close()
        for writer in list(self._writers):
            writer.close()
        self._loop.stop()


@contextlib.contextmanager
def silent_broker() -> Iterator[SilentBroker]:
    """A ``SilentBroker`` listening on a free port while the block runs."""
    broker = SilentBroker()
    ready = threading.Event()
    thread = threading.Thread(target=broker._thread_main, args=(ready,), daemon=True)
    thread.start()
    if not ready.wait(10):
        msg = "the silent broker did not start"
        raise AssertionError(msg)
    try:
        yield broker
    finally:
        broker._loop.call_soon_threadsafe(broker._shutdown)
        thread.join(10)
