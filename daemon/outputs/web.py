"""The browser live view: one self-contained page and a Server-Sent Events feed.

``scotti-daemon --web 8080`` -> http://localhost:8080/ shows both pressure
maps with a colour scale, the skeleton in 3D (drag to turn it), the action
with its confidence, progress with the repetition count, status and latency.
The page (``web_view.html``, vanilla JS and canvas, no library, no CDN) works
without internet; the feed is ``/events``, one JSON object per prediction
and per status change. SSE rather than WebSocket: plain HTTP, no dependency
here, reconnects by itself in the browser.

A slow browser never holds up the daemon: each client has a short queue that
drops its oldest frame.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
from importlib import resources
from typing import Any, Final

import numpy as np
from scotti.daemon.outputs import OutputError
from scotti.daemon.pipeline import Prediction
from scotti.daemon.schemas import Status
from scotti.models.contract import ACTIONS, BONE_INDEX, FRAME_COLS, KEYPOINTS, MAX_COUNT, NO_ACTION

log = logging.getLogger(__name__)

CLIENT_QUEUE: Final = 8  # frames a client may fall behind before its oldest are dropped
PAGE: Final = "web_view.html"


def frame_event(p: Prediction, latency_ms: float) -> dict[str, Any]:
    probs = [round(float(x), 4) for x in p.action_probs]
    action = ACTIONS[p.action] if p.action != NO_ACTION else None
    progress = None if p.progress is None or not np.isfinite(p.progress) else float(p.progress)
    counts = np.asarray(p.counts)
    return {
        "type": "frame",
        "seq": p.seq,
        "device_time_us": p.device_clock_us,
        "host_wall_ns": p.host_wall_ns,
        "latency_ms": round(latency_ms, 2),
        "inference_ms": round(p.inference_ms, 2),
        "flags": list(p.flags),
        "action": action,
        "confidence": probs[p.action] if action is not None else 0.0,
        "probabilities": probs,
        "progress": progress,
        "repetition": p.repetition,
        "withheld": p.withheld,  # unloaded, out_of_range or unfamiliar: no action
        "unfamiliar_score": p.unfamiliar_score,
        "pose": np.round(np.asarray(p.pose, dtype=np.float64), 4).tolist(),
        "rows": int(counts.shape[0]),
        "cols": FRAME_COLS,
        "left": counts[:, :FRAME_COLS].ravel().tolist(),
        "right": counts[:, FRAME_COLS:].ravel().tolist(),
    }


def hello_event() -> dict[str, Any]:
    """What the page needs once: names, bones, the counts' full scale."""
    return {
        "type": "hello",
        "actions": list(ACTIONS),
        "keypoints": list(KEYPOINTS),
        "bones": BONE_INDEX.tolist(),
        "max_count": MAX_COUNT,
    }


def _sse(event: dict[str, Any]) -> bytes:
    return b"data: " + json.dumps(event, separators=(",", ":")).encode() + b"\n\n"


class WebOutput:
    name = "web"

    def __init__(self, server: asyncio.Server) -> None:
        self.server = server
        self.port: int = server.sockets[0].getsockname()[1]
        self.host: str = server.sockets[0].getsockname()[0]
        self._clients: set[asyncio.Queue[bytes]] = set()
        self._status: bytes | None = None
        self._page = resources.files("scotti.daemon.outputs").joinpath(PAGE).read_bytes()

    @classmethod
    async def start(cls, host: str, port: int) -> WebOutput:
        holder: list[WebOutput] = []

        async def handle(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            await holder[0]._handle(reader, writer)

        try:
            server = await asyncio.start_server(handle, host, port)
        except OSError as exc:
            msg = f"--web: cannot listen on {host}:{port}: {exc.strerror}"
            raise OutputError(msg) from None
        holder.append(cls(server))
        return holder[0]

    def __str__(self) -> str:
        return f"web: live view on http://{self.host}:{self.port}/"

    def prediction(self, p: Prediction, latency_ms: float) -> None:
        if self._clients:
            self._broadcast(_sse(frame_event(p, latency_ms)))

    def status(self, status: Status) -> None:
        self._status = _sse({"type": "status", **status.model_dump(mode="json")})
        self._broadcast(self._status)

    async def close(self) -> None:
        self.server.close()
        for queue in list(self._clients):
            queue.put_nowait(b"")  # b"": the stream ends
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(self.server.wait_closed(), 1.0)

    def _broadcast(self, data: bytes) -> None:
        for queue in self._clients:
            if queue.full():
                queue.get_nowait()  # drop the oldest: the browser sees the newest
            queue.put_nowait(data)

    async def _handle(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            request = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), 5.0)
            parts = request.split(b" ", 2)
            path = parts[1].decode("ascii", "replace") if len(parts) > 1 else ""
            if parts[0] != b"GET":
                await _respond(writer, "405 Method Not Allowed", "text/plain", b"GET only\n")
            elif path in ("/", "/index.html"):
                await _respond(writer, "200 OK", "text/html; charset=utf-8", self._page)
            elif path == "/events":
                await self._stream(writer)
            else:
                await _respond(writer, "404 Not Found", "text/plain", b"not found\n")
        except (OSError, TimeoutError, asyncio.IncompleteReadError, asyncio.LimitOverrunError):
            pass  # a client that went away or sent nonsense: nothing to answer
        finally:
            writer.close()
            with contextlib.suppress(OSError):
                await writer.wait_closed()

    async def _stream(self, writer: asyncio.StreamWriter) -> None:
        writer.write(
            b"HTTP/1.1 200 OK\r\nContent-Type: text/event-stream\r\n"
            b"Cache-Control: no-store\r\nConnection: close\r\n\r\n"
        )
        writer.write(_sse(hello_event()))
        if self._status is not None:
            writer.write(self._status)
        queue: asyncio.Queue[bytes] = asyncio.Queue(CLIENT_QUEUE)
        self._clients.add(queue)
        try:
            while data := await queue.get():
                writer.write(data)
                await writer.drain()
        finally:
            self._clients.discard(queue)


async def _respond(writer: asyncio.StreamWriter, status: str, kind: str, body: bytes) -> None:
    head = (
        f"HTTP/1.1 {status}\r\nContent-Type: {kind}\r\nContent-Length: {len(body)}\r\n"
        "Cache-Control: no-store\r\nConnection: close\r\n\r\n"
    )
    writer.write(head.encode() + body)
    await writer.drain()
