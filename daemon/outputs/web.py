"""The browser live view: one self-contained page and a Server-Sent Events feed.

``scotti-daemon --web 8080`` -> http://localhost:8080/ shows both pressure
maps with a colour scale, the skeleton in 3D (drag to turn it), the action
with its confidence, progress with the repetition count, status and latency.
The page (``web_view.html``, vanilla JS and canvas, no library, no CDN) works
without internet; the feed is ``events`` beside it, one JSON object per
prediction and per status change. SSE rather than WebSocket: plain HTTP, no
dependency here, reconnects by itself in the browser.

Every device has its view at ``/devices/<id>/`` (feed ``/devices/<id>/events``)
and ``/devices`` lists them as JSON. ``/`` is the view of a lone device (and
``/events`` its feed, as always), or the list of devices when there are
several; each view has a chooser of the others.

A slow browser never holds up the daemon nor another browser: each client
has a short queue that drops its oldest frame. Events are rendered on the
outputs' thread, and only for a device someone watches.
"""

from __future__ import annotations

import asyncio
import contextlib
import html
import json
import logging
import urllib.parse
from collections.abc import Sequence
from importlib import resources
from typing import Any, Final

import numpy as np
from scotti.daemon.frames.pipeline import Prediction
from scotti.daemon.mqtt.schemas import Status
from scotti.daemon.outputs import OutputError
from scotti.models.contract import ACTIONS, BONE_INDEX, FRAME_COLS, KEYPOINTS, MAX_COUNT, NO_ACTION

log = logging.getLogger(__name__)

CLIENT_QUEUE: Final = 8  # frames a client may fall behind before its oldest are dropped
PAGE: Final = "web_view.html"
HTML: Final = "text/html; charset=utf-8"


def frame_event(p: Prediction, latency_ms: float, device: str = "") -> dict[str, Any]:
    probs = [round(float(x), 4) for x in p.action_probs]
    action = ACTIONS[p.action] if p.action != NO_ACTION else None
    progress = None if p.progress is None or not np.isfinite(p.progress) else float(p.progress)
    counts = np.asarray(p.counts)
    return {
        "type": "frame",
        "device": device,
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


def hello_event(device: str = "", devices: Sequence[str] = ()) -> dict[str, Any]:
    """What the page needs once: its device and the others (the chooser), names, bones,
    the counts' full scale."""
    return {
        "type": "hello",
        "device": device,
        "devices": list(devices),
        "actions": list(ACTIONS),
        "keypoints": list(KEYPOINTS),
        "bones": BONE_INDEX.tolist(),
        "max_count": MAX_COUNT,
    }


def _sse(event: dict[str, Any]) -> bytes:
    return b"data: " + json.dumps(event, separators=(",", ":")).encode() + b"\n\n"


class WebOutput:
    """One server for every device: ``/devices/<id>/`` is a device's view, ``/`` the view
    of a lone device or the list of several."""

    name = "web"

    def __init__(
        self, server: asyncio.Server, devices: Sequence[str], loop: asyncio.AbstractEventLoop
    ) -> None:
        self.server = server
        self.port: int = server.sockets[0].getsockname()[1]
        self.host: str = server.sockets[0].getsockname()[0]
        self.devices = tuple(devices)
        self._loop = loop
        # Touched on the event loop only; the outputs' thread reads ``_clients`` to skip
        # rendering a device nobody watches (a stale answer costs one frame, no more).
        self._clients: dict[str, set[asyncio.Queue[bytes]]] = {d: set() for d in self.devices}
        self._status: dict[str, bytes] = {}
        self._state: dict[str, tuple[str, list[str]]] = {}  # the device list's column
        self._page = resources.files("scotti.daemon.outputs").joinpath(PAGE).read_bytes()

    @classmethod
    async def start(cls, host: str, port: int, devices: Sequence[str] = ("scotti",)) -> WebOutput:
        holder: list[WebOutput] = []

        async def handle(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            await holder[0]._handle(reader, writer)

        try:
            server = await asyncio.start_server(handle, host, port)
        except OSError as exc:
            msg = f"--web: cannot listen on {host}:{port}: {exc.strerror or exc}"
            raise OutputError(msg) from None
        holder.append(cls(server, devices, asyncio.get_running_loop()))
        return holder[0]

    def __str__(self) -> str:
        where = f"http://{self.host}:{self.port}/"
        if len(self.devices) > 1:
            return (
                f"web: {len(self.devices)} devices listed on {where}, each on {where}devices/<id>/"
            )
        return f"web: live view on {where}"

    # --- from the outputs' thread -------------------------------------------------------
    def prediction(self, device: str, p: Prediction, latency_ms: float) -> None:
        if self._clients[device]:  # rendered here, off the loop; only sent there
            data = _sse(frame_event(p, latency_ms, device))
            self._loop.call_soon_threadsafe(self._broadcast, device, data)

    def status(self, device: str, status: Status) -> None:
        data = _sse({"type": "status", "device": device, **status.model_dump(mode="json")})
        state = (status.state, list(status.reasons))
        self._loop.call_soon_threadsafe(self._set_status, device, data, state)

    async def close(self) -> None:
        self.server.close()
        for device in self.devices:  # b"": the stream ends, after what its queue holds
            self._broadcast(device, b"")  # (a full queue drops its oldest, never raises)
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(self.server.wait_closed(), 1.0)

    # --- on the event loop ----------------------------------------------------------
    def _set_status(self, device: str, data: bytes, state: tuple[str, list[str]]) -> None:
        self._status[device] = data
        self._state[device] = state
        self._broadcast(device, data)

    def _broadcast(self, device: str, data: bytes) -> None:
        for queue in self._clients[device]:
            if queue.full():
                queue.get_nowait()  # drop the oldest: the browser sees the newest
            queue.put_nowait(data)

    async def _handle(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            request = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), 5.0)
            parts = request.split(b" ", 2)
            target = parts[1].decode("ascii", "replace") if len(parts) > 1 else ""
            path = urllib.parse.unquote(target.split("?", 1)[0])
            if parts[0] != b"GET":
                await _respond(writer, "405 Method Not Allowed", "text/plain", b"GET only\n")
            else:
                await self._route(path, writer)
        except (OSError, TimeoutError, asyncio.IncompleteReadError, asyncio.LimitOverrunError):
            pass  # a client that went away or sent nonsense: nothing to answer
        finally:
            writer.close()
            with contextlib.suppress(OSError):
                await writer.wait_closed()

    async def _route(self, path: str, writer: asyncio.StreamWriter) -> None:
        lone = self.devices[0] if len(self.devices) == 1 else None
        device, _, rest = path.removeprefix("/devices/").partition("/")
        if path in ("/", "/index.html"):
            if lone is not None:  # a one-pair daemon's view, where it always was
                await _respond(writer, "200 OK", HTML, self._page)
            else:
                await _respond(writer, "200 OK", HTML, self._device_list_page())
        elif path == "/events" and lone is not None:
            await self._stream(lone, writer)
        elif path in ("/devices", "/devices.json"):
            body = json.dumps(self._device_list()).encode()
            await _respond(writer, "200 OK", "application/json", body)
        elif path.startswith("/devices/") and device in self._clients:
            if path == f"/devices/{device}":  # the page's relative "events" needs the slash
                await _redirect(writer, f"/devices/{urllib.parse.quote(device)}/")
            elif rest in ("", "index.html"):
                await _respond(writer, "200 OK", HTML, self._page)
            elif rest == "events":
                await self._stream(device, writer)
            else:
                await _respond(writer, "404 Not Found", "text/plain", b"not found\n")
        elif path == "/events":
            body = b"several devices: each has its feed at /devices/<id>/events\n"
            await _respond(writer, "404 Not Found", "text/plain", body)
        else:
            await _respond(writer, "404 Not Found", "text/plain", b"not found\n")

    def _device_list(self) -> list[dict[str, Any]]:
        out = []
        for device in self.devices:
            state, reasons = self._state.get(device, ("starting", []))
            view = f"/devices/{urllib.parse.quote(device)}/"
            out.append({"id": device, "state": state, "reasons": reasons, "view": view})
        return out

    def _device_list_page(self) -> bytes:
        rows = "".join(
            f'<tr><td><a href="{html.escape(d["view"])}">{html.escape(d["id"])}</a></td>'
            f'<td class="{html.escape(d["state"])}">{html.escape(d["state"])}</td>'
            f"<td>{html.escape('; '.join(d['reasons']))}</td></tr>"
            for d in self._device_list()
        )
        return DEVICE_LIST.format(count=len(self.devices), rows=rows).encode()

    async def _stream(self, device: str, writer: asyncio.StreamWriter) -> None:
        writer.write(
            b"HTTP/1.1 200 OK\r\nContent-Type: text/event-stream\r\n"
            b"Cache-Control: no-store\r\nConnection: close\r\n\r\n"
        )
        writer.write(_sse(hello_event(device, self.devices)))
        if device in self._status:
            writer.write(self._status[device])
        queue: asyncio.Queue[bytes] = asyncio.Queue(CLIENT_QUEUE)
        clients = self._clients[device]
        clients.add(queue)
        try:
            while data := await queue.get():
                writer.write(data)
                await writer.drain()
        finally:
            clients.discard(queue)


# The list of devices (several only): refreshed every few seconds, each a link to its view.
DEVICE_LIST: Final = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><meta http-equiv="refresh" content="5">
<title>scotti devices</title>
<style>
  body {{ font: 14px system-ui, sans-serif; background: #111; color: #ddd; margin: 12px; }}
  a {{ color: #4c9be8; }} td, th {{ padding: 2px 12px 2px 0; text-align: left; }}
  .online {{ color: #6c6; }} .degraded {{ color: #e6b34c; }} .offline {{ color: #e66; }}
</style></head>
<body><h1 style="font-size: 16px">scotti live: {count} devices</h1>
<table id="devices"><tr><th>device</th><th>status</th><th>why</th></tr>{rows}</table>
</body></html>
"""


async def _redirect(writer: asyncio.StreamWriter, location: str) -> None:
    head = (
        f"HTTP/1.1 301 Moved Permanently\r\nLocation: {location}\r\nContent-Length: 0\r\n"
        "Connection: close\r\n\r\n"
    )
    writer.write(head.encode())
    await writer.drain()


async def _respond(writer: asyncio.StreamWriter, status: str, kind: str, body: bytes) -> None:
    head = (
        f"HTTP/1.1 {status}\r\nContent-Type: {kind}\r\nContent-Length: {len(body)}\r\n"
        "Cache-Control: no-store\r\nConnection: close\r\n\r\n"
    )
    writer.write(head.encode() + body)
    await writer.drain()
