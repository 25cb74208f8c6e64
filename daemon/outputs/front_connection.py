"""One client connection of the front's process: its request head, then a page, a feed or a pipe.

``Connection`` reads and checks the request head (``guard``), hands it to the
web routes or pipes it to the Foxglove server (``Upstream``), and queues a
feed's events for a slow reader (``CLIENT_QUEUE``, oldest dropped). The
listening, the daemon's channel and the counters are ``front.Front``'s.
"""

from __future__ import annotations

import asyncio
import collections
from typing import TYPE_CHECKING, Final

from scotti.daemon.outputs import guard

if TYPE_CHECKING:  # front runs as __main__: a runtime import would load it a second time
    from scotti.daemon.outputs.front import Front

CLIENT_QUEUE: Final = 8  # events a reader may fall behind beyond the kernel's buffer
WRITE_HIGH: Final = 64 * 1024  # a reader's buffer above this: its events queue (and drop)
HEAD_TIMEOUT_S: Final = 5.0  # a connection that sends no request head in this is closed


class Connection(asyncio.Protocol):
    """One client: its request head, checked; then a page, a feed, or a pipe upstream."""

    def __init__(self, front: Front) -> None:
        self.front = front
        self.transport: asyncio.Transport | None = None
        self.head = b""
        self.timer: asyncio.TimerHandle | None = None
        self.queue: collections.deque[bytes] = collections.deque()
        self.paused = False
        self.device: int | None = None  # a feed's device, once it reads one
        self.peer: Upstream | None = None  # the proxy's other side
        self.done = False

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.transport = transport
        self.front.open.add(self)
        transport.set_write_buffer_limits(high=WRITE_HIGH)
        self.timer = self.front.loop.call_later(HEAD_TIMEOUT_S, transport.close)

    def data_received(self, data: bytes) -> None:
        if self.done:
            if self.peer is not None and self.peer.transport is not None:
                self.peer.transport.write(data)
            elif self.front.upstream is not None:
                self.head += data  # before the upstream answered: sent with the head
            return  # a feed's reader has nothing more to say
        self.head += data
        end = self.head.find(b"\r\n\r\n")
        if end < 0:
            if len(self.head) > guard.HEAD_LIMIT:
                self.refuse(guard.BAD_REQUEST)
            return
        self.done = True
        if self.timer is not None:
            self.timer.cancel()
        request = guard.parse_head(self.head[: end + 2])
        reason = guard.refusal(request, self.front.rules)
        if reason is not None or request is None:
            self.refuse(reason or guard.BAD_REQUEST)
        elif self.front.routes is not None:
            self.front.routes.route(self, request)
        else:
            assert self.transport is not None
            self.transport.pause_reading()
            self.front.loop.create_task(self.pipe_upstream())

    def refuse(self, reason: str) -> None:
        self.done = True
        self.front.refused(reason)
        assert self.transport is not None
        self.transport.write(guard.answer(reason))
        self.transport.close()

    def respond(self, status: str, kind: str, body: bytes, extra: str = "") -> None:
        head = (
            f"HTTP/1.1 {status}\r\nContent-Type: {kind}\r\nContent-Length: {len(body)}\r\n"
            f"{extra}Cache-Control: no-store\r\nConnection: close\r\n\r\n"
        )
        assert self.transport is not None
        self.transport.write(head.encode() + body)
        self.transport.close()

    # --- a feed -------------------------------------------------------------------------
    def send(self, data: bytes) -> None:
        """Now when the reader keeps up, else queued; a full queue drops its oldest."""
        if not self.paused and not self.queue:
            assert self.transport is not None
            self.transport.write(data)
            return
        if len(self.queue) >= CLIENT_QUEUE:
            self.queue.popleft()
            self.front.dropped += 1
            self.front.counters_changed()
        self.queue.append(data)

    def end(self) -> None:
        """Closes; a feed after what it has queued."""
        assert self.transport is not None
        while self.queue:
            self.transport.write(self.queue.popleft())
        self.transport.close()

    def pause_writing(self) -> None:
        self.paused = True
        if self.peer is not None and self.peer.transport is not None:
            self.peer.transport.pause_reading()

    def resume_writing(self) -> None:
        self.paused = False
        while self.queue and not self.paused:
            assert self.transport is not None
            self.transport.write(self.queue.popleft())
        if self.peer is not None and self.peer.transport is not None:
            self.peer.transport.resume_reading()

    def connection_lost(self, exc: Exception | None) -> None:
        if self.timer is not None:
            self.timer.cancel()
        if self.front.routes is not None and self.device is not None:
            self.front.routes.leave(self)
        if self.peer is not None and self.peer.transport is not None:
            self.peer.transport.close()
        self.front.open.discard(self)
        self.front.gone()

    # --- the proxy ----------------------------------------------------------------------
    async def pipe_upstream(self) -> None:
        assert self.transport is not None
        assert self.front.upstream is not None
        try:
            await self.front.loop.create_connection(lambda: Upstream(self), *self.front.upstream)
        except OSError:
            self.respond("502 Bad Gateway", "text/plain", b"the server behind is not there\n")
            return
        assert self.peer is not None
        assert self.peer.transport is not None
        self.peer.transport.write(self.head)
        self.head = b""
        if not self.transport.is_closing():
            self.transport.resume_reading()


class Upstream(asyncio.Protocol):
    """The Foxglove server's side of one proxied connection."""

    def __init__(self, client: Connection) -> None:
        self.client = client
        self.transport: asyncio.Transport | None = None
        client.peer = self

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.transport = transport
        transport.set_write_buffer_limits(high=WRITE_HIGH)

    def data_received(self, data: bytes) -> None:
        if self.client.transport is not None:
            self.client.transport.write(data)

    def pause_writing(self) -> None:
        if self.client.transport is not None:
            self.client.transport.pause_reading()

    def resume_writing(self) -> None:
        if self.client.transport is not None and not self.client.transport.is_closing():
            self.client.transport.resume_reading()

    def connection_lost(self, exc: Exception | None) -> None:
        if self.client.transport is not None:
            self.client.transport.close()
