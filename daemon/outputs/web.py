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

The server is a process of its own (``front.py``, started through
``front_process``): the browsers' connections, their descriptors and the
copying of each event to every reader are that process's, so a thousand
readers or a flood of connections never slow the daemon's MQTT path nor take
its descriptors. Each event is rendered here once, on the outputs' thread,
and only for a device someone watches; a slow browser's short queue there
drops its oldest frame. ``guard`` decides who may connect (a cap, Host,
Origin, an optional token).
"""

from __future__ import annotations

import json
import logging
from collections.abc import Sequence
from importlib import resources
from typing import Any, Final

import numpy as np
from scotti.daemon.frames.pipeline import Prediction
from scotti.daemon.mqtt.schemas import Status
from scotti.daemon.outputs import guard
from scotti.daemon.outputs.front import FRAME
from scotti.daemon.outputs.front_process import FrontProcess, listen
from scotti.models.contract import ACTIONS, BONE_INDEX, FRAME_COLS, KEYPOINTS, MAX_COUNT, NO_ACTION

log = logging.getLogger(__name__)

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

    def __init__(self, front: FrontProcess, host: str, port: int, devices: Sequence[str]) -> None:
        self.front = front
        self.host = host
        self.port = port
        self.devices = tuple(devices)
        self._index = {d: i for i, d in enumerate(self.devices)}

    @classmethod
    async def start(
        cls,
        host: str,
        port: int,
        devices: Sequence[str] = ("scotti",),
        rules: guard.Rules | None = None,
    ) -> WebOutput:
        """``rules``: who may connect (default: ``guard.Rules()`` bound to ``host``)."""
        listener = listen(host, port, "--web")
        bound_host, bound_port = listener.getsockname()[:2]
        rules = rules or guard.Rules()
        rules = guard.Rules(
            max_connections=rules.max_connections,
            bound_host=host,
            allowed_hosts=rules.allowed_hosts,
            allowed_origins=rules.allowed_origins,
            token=rules.token,
        )
        page = resources.files("scotti.daemon.outputs").joinpath(PAGE).read_text("utf-8")
        config = {
            "mode": "web",
            "devices": list(devices),
            "hello": [_sse(hello_event(d, devices)).decode() for d in devices],
            "page": page,
        }
        front = FrontProcess.start("web", listener, rules, config)
        return cls(front, bound_host, bound_port, devices)

    def __str__(self) -> str:
        where = f"http://{self.host}:{self.port}/"
        if len(self.devices) > 1:
            return (
                f"web: {len(self.devices)} devices listed on {where}, each on {where}devices/<id>/"
            )
        return f"web: live view on {where}"

    @property
    def counters(self) -> dict[str, Any]:
        """Connections now, the cap, refusals by reason, events slow readers never got,
        frames the server's process had no room for (``unsent``)."""
        return {**self.front.counters, "unsent": self.front.unsent}

    # --- from the outputs' thread -------------------------------------------------------
    def prediction(self, device: str, p: Prediction, latency_ms: float) -> None:
        index = self._index[device]
        if index in self.front.watched:  # rendered here, off the loop, once for every reader
            self.front.send(FRAME, index, _sse(frame_event(p, latency_ms, device)))

    def status(self, device: str, status: Status) -> None:
        data = _sse({"type": "status", "device": device, **status.model_dump(mode="json")})
        message = {"sse": data.decode(), "state": status.state, "reasons": list(status.reasons)}
        self.front.send_status(self._index[device], message)

    async def close(self) -> None:
        """Every feed ends after what its queue holds; the port is free on return."""
        await self.front.close()
