"""A live terminal view of one daemon, subscribed over MQTT like any consumer.

Both insoles as ANSI heat maps (needs the optional ``pressure`` topic), the
action with its confidence and every action's probability, a progress bar
with the repetition count, status and latency. ``render`` is a pure function
of what arrived, so it is tested without a terminal.

    python -m scotti.daemon.tools.viewer --broker mqtt://localhost:1883 [--device ID]
"""

from __future__ import annotations

import argparse
import asyncio
import collections
import contextlib
import json
import sys
import time
from dataclasses import dataclass, field
from typing import Any, Final, TextIO

import aiomqtt
import msgpack
import numpy as np
from scotti.daemon.config_checks import ConfigError
from scotti.daemon.mqtt_settings import MqttSettings
from scotti.daemon.waiting import wait_event
from scotti.models.contract import ACTIONS, MAX_COUNT, has_progress

# xterm-256 colours from cold to hot (blue, cyan, green, yellow, red).
_RAMP: Final = (16, 17, 18, 19, 20, 21, 27, 33, 39, 45, 51, 50, 49, 48, 47, 46, 82, 118, 154)
_RAMP_HOT: Final = (190, 226, 220, 214, 208, 202, 196)
PALETTE: Final = _RAMP + _RAMP_HOT
RESET: Final = "\x1b[0m"
BAR_WIDTH: Final = 30


@dataclass
class ViewState:
    """The newest message of each kind, decoded to plain dicts."""

    topic: str = ""
    latest: dict[str, dict[str, Any]] = field(default_factory=dict)
    frames_seen: int = 0
    arrivals: collections.deque[float] = field(default_factory=lambda: collections.deque(maxlen=33))
    first_pose: asyncio.Event = field(default_factory=asyncio.Event)  # set at the first pose

    def update(self, name: str, data: dict[str, Any], topic: str) -> None:
        self.latest[name] = data
        if name == "pose":
            self.frames_seen += 1
            self.first_pose.set()
            self.arrivals.append(time.monotonic())
            self.topic = topic.rsplit("/", 1)[0]

    @property
    def rate_hz(self) -> float:
        """Poses per second over the last 32 arrivals (0 once they stop for 1 s)."""
        if len(self.arrivals) < 2 or time.monotonic() - self.arrivals[-1] > 1.0:
            return 0.0
        return (len(self.arrivals) - 1) / max(1e-3, self.arrivals[-1] - self.arrivals[0])


def decode_payload(payload: bytes, content_type: str | None) -> dict[str, Any] | None:
    """A message body as a dict, by its v5 content type (JSON when absent)."""
    try:
        if content_type == "application/msgpack":
            data = msgpack.unpackb(payload, raw=False, strict_map_key=False)
        else:
            data = json.loads(payload)
    except (ValueError, msgpack.UnpackException):
        return None
    return data if isinstance(data, dict) else None


def pressure_grid(data: dict[str, Any], side: str) -> np.ndarray | None:
    raw = data.get(side)
    if isinstance(raw, str):  # JSON: base64url
        import base64

        raw = base64.urlsafe_b64decode(raw + "=" * (-len(raw) % 4))
    if not isinstance(raw, bytes):
        return None
    rows, cols = int(data["rows"]), int(data["cols"])
    if len(raw) != rows * cols * 2:
        return None
    return np.frombuffer(raw, dtype="<u2").reshape(rows, cols)


def heat_rows(grid: np.ndarray) -> list[str]:
    """One string per row: two spaces per cell on a background colour."""
    level = np.sqrt(np.clip(grid.astype(np.float32) / MAX_COUNT, 0.0, 1.0))
    index = np.minimum((level * len(PALETTE)).astype(int), len(PALETTE) - 1)
    return ["".join(f"\x1b[48;5;{PALETTE[i]}m  " for i in row) + RESET for row in index]


def scale_row(cells: int = 16) -> str:
    """The colour key under the maps: the ramp from 0 to full scale, labelled in counts.

    The maps use a square-root scale (light loads stay visible), so the middle of the
    ramp is a quarter of full scale.
    """
    levels = np.linspace(0.0, 1.0, cells)
    index = np.minimum((levels * len(PALETTE)).astype(int), len(PALETTE) - 1)
    ramp = "".join(f"\x1b[48;5;{PALETTE[i]}m  " for i in index) + RESET
    quarter = round(MAX_COUNT / 4)
    return f"  0 {ramp} {MAX_COUNT} counts (square-root scale: mid-ramp = {quarter})"


def bar(fraction: float, width: int = BAR_WIDTH) -> str:
    filled = round(max(0.0, min(1.0, fraction)) * width)
    return "█" * filled + "░" * (width - filled)


def render(state: ViewState, width: int = 100) -> str:
    lines = [_header(state), ""]
    lines += _feet(state.latest.get("pressure"))
    lines.append("")
    lines += _action(state.latest.get("action"))
    lines.append(_progress(state.latest.get("progress")))
    lines.append(_latency(state))
    return "\n".join(line if "\x1b" in line else line[:width] for line in lines)


def _header(state: ViewState) -> str:
    status = state.latest.get("status", {})
    st = status.get("state", "waiting")
    colour = {"online": 32, "degraded": 33, "offline": 31}.get(st, 37)
    reasons = ", ".join(status.get("reasons", []))
    where = state.topic or "waiting for the daemon"
    return f"SCOTTI  {where}   status \x1b[{colour}m{st}{RESET}" + (
        f" ({reasons})" if reasons else ""
    )


def _feet(pressure: dict[str, Any] | None) -> list[str]:
    if pressure is None:
        return ["  (no pressure frames: the daemon publishes them with --pressure)"]
    left, right = pressure_grid(pressure, "left"), pressure_grid(pressure, "right")
    if left is None or right is None:
        return ["  (pressure frame unreadable)"]
    pad = " " * (2 * left.shape[1] - 4)
    out = ["  left" + pad + "    right"]
    out += [f"  {a}    {b}" for a, b in zip(heat_rows(left), heat_rows(right), strict=True)]
    out.append(scale_row())
    return out


def _action(action: dict[str, Any] | None) -> list[str]:
    if action is None:
        return ["action    (waiting)"]
    name = action.get("action") or (
        f"withheld: {action['withheld']}" if action.get("withheld") else "none"
    )
    out = [f"action    \x1b[1m{name}\x1b[0m  confidence {action.get('confidence', 0.0):.2f}"]
    for act, p in sorted(action.get("probabilities", {}).items(), key=lambda kv: -kv[1]):
        out.append(f"  {act:<18} {bar(p, 20)} {p:5.2f}")
    return out


# Actions that run no repetitions (standing): no progress bar, no count.
WITHOUT_PROGRESS: Final = frozenset(a for i, a in enumerate(ACTIONS) if not has_progress(i))


def _progress(progress: dict[str, Any] | None) -> str:
    if progress is None:
        return "progress  (waiting)"
    if progress.get("action") in WITHOUT_PROGRESS:
        return f"progress  ({progress['action']}: no repetition running)"
    value = progress.get("progress")
    rep = progress.get("repetition", -1)
    reps = f"rep {rep}" if rep >= 0 else "no repetition"
    if value is None:
        return f"progress  {'-' * BAR_WIDTH}   ----  {reps}"
    return f"progress  {bar(value)}  {value:4.2f}  {reps}  ({progress.get('action')})"


def _latency(state: ViewState) -> str:
    pose = state.latest.get("pose", {})
    health = state.latest.get("health", {})
    p99 = health.get("end_to_end", {}).get("p99_ms")
    rate = state.rate_hz
    text = f"latency   {pose.get('latency_ms', float('nan')):6.1f} ms (last byte -> publish)"
    if p99 is not None:
        text += f", p99 {p99:.1f} ms"
    text += f"   seq {pose.get('seq', '-')}   {rate:4.1f} frames/s"
    if health:
        text += f"   dropped {health.get('dropped', 0)}"
    return text


async def run_viewer(
    settings: MqttSettings,
    stop: asyncio.Event,
    *,
    device: str = "+",
    out: TextIO = sys.stdout,
    fps: float = 8.0,
    state: ViewState | None = None,
) -> ViewState:
    """Subscribe and redraw until ``stop``; reconnects while the broker is away.

    ``state``: the caller's own, to watch while the view runs (the demo waits
    for its first frame); a fresh one when None.
    """
    state = ViewState() if state is None else state
    drawer = asyncio.create_task(_draw(state, stop, out, fps))
    topic = f"{settings.topic_prefix}/{device}/#"
    try:
        while not stop.is_set():
            try:
                v5 = settings.protocol == "5"
                protocol = aiomqtt.ProtocolVersion.V5 if v5 else aiomqtt.ProtocolVersion.V311
                async with aiomqtt.Client(
                    settings.host, settings.port, protocol=protocol
                ) as client:
                    await client.subscribe(topic, qos=1)
                    reader = asyncio.create_task(_read(client, state))
                    await stop.wait()
                    reader.cancel()
                    with contextlib.suppress(asyncio.CancelledError):
                        await reader
            except aiomqtt.MqttError:
                await wait_event(stop, 0.5)
    finally:
        stop.set()
        await drawer
    return state


async def _read(client: aiomqtt.Client, state: ViewState) -> None:
    async for message in client.messages:
        topic = str(message.topic)
        ct = getattr(message.properties, "ContentType", None)
        data = decode_payload(bytes(message.payload), ct)
        if data is not None:
            state.update(topic.rsplit("/", 1)[1], data, topic)


async def _draw(state: ViewState, stop: asyncio.Event, out: TextIO, fps: float) -> None:
    out.write("\x1b[?1049h\x1b[?25l")  # alternate screen, hide the cursor
    try:
        while not stop.is_set():
            out.write("\x1b[H" + render(state).replace("\n", "\x1b[K\n") + "\x1b[K\x1b[J")
            out.flush()
            await wait_event(stop, 1 / fps)
    finally:
        out.write("\x1b[?25h\x1b[?1049l")  # cursor back, main screen back
        out.flush()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m scotti.daemon.tools.viewer")
    parser.add_argument("--broker", default="mqtt://localhost:1883")
    parser.add_argument("--topic-prefix", default="scotti")
    parser.add_argument("--device", default="+", help="device id (default: any)")
    parser.add_argument("--duration", type=float, default=0, help="seconds, 0 = until Ctrl-C")
    args = parser.parse_args(argv)
    try:
        settings = MqttSettings(broker=args.broker, topic_prefix=args.topic_prefix)
    except ValueError as exc:
        print(f"viewer: {ConfigError(str(exc).splitlines()[-1])}", file=sys.stderr)
        return 78

    async def go() -> None:
        stop = asyncio.Event()
        if args.duration:
            asyncio.get_running_loop().call_later(args.duration, stop.set)
        await run_viewer(settings, stop, device=args.device)

    with contextlib.suppress(KeyboardInterrupt):
        asyncio.run(go())
    return 0


if __name__ == "__main__":
    sys.exit(main())
