"""A live terminal view of one daemon, subscribed over MQTT like any consumer.

On a terminal: both insoles as heat maps (needs the optional ``pressure``
topic), every action's probability beside them, the action with its
confidence, a progress bar with the repetition count, status and latency, in
80 columns by 24 lines. When stdout is not a terminal (a pipe, a file, a
log): one plain line a second, no escape codes. ``render`` and ``plain_line``
are pure functions of what arrived, so they are tested without a terminal.

    python -m scotti.daemon.tools.viewer --broker mqtt://localhost:1883 [--device ID] [--plain]
"""

from __future__ import annotations

import argparse
import asyncio
import collections
import contextlib
import json
import re
import sys
import time
from dataclasses import dataclass, field
from typing import Any, Final, TextIO

import aiomqtt
import msgpack
import numpy as np
import numpy.typing as npt
from scotti.daemon.settings.checks import ConfigError
from scotti.daemon.settings.mqtt import MqttSettings
from scotti.daemon.waiting import wait_event
from scotti.models.contract import ACTIONS, MAX_COUNT, has_progress

# xterm-256 colours from cold to hot (blue, cyan, green, yellow, red).
_RAMP: Final = (16, 17, 18, 19, 20, 21, 27, 33, 39, 45, 51, 50, 49, 48, 47, 46, 82, 118, 154)
_RAMP_HOT: Final = (190, 226, 220, 214, 208, 202, 196)
PALETTE: Final = _RAMP + _RAMP_HOT
RESET: Final = "\x1b[0m"
WIDTH: Final = 80  # the screen the view fits: 80 columns by 24 lines
HEIGHT: Final = 24
BAR_WIDTH: Final = 30  # the progress bar
MAP_WIDTH: Final = 22  # characters per insole map (the insole's 22 columns)
MAP_LINES: Final = 16  # lines per map: 32 rows of half-block cells
FEET_WIDTH: Final = 2 + MAP_WIDTH + 2 + MAP_WIDTH  # the maps and their margins: 48
NAME_WIDTH: Final = 16  # the longest action name (backward_walking)
PROB_BAR: Final = 7  # beside the maps: 2 + 16 + 1 + 7 + 1 + 4 = 31 columns
PLAIN_EVERY_S: Final = 1.0  # a plain line this often


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


def _levels(grid: np.ndarray) -> npt.NDArray[np.int64]:
    """Palette indices of counts: a square-root scale, so light loads stay visible."""
    level = np.sqrt(np.clip(grid.astype(np.float32) / MAX_COUNT, 0.0, 1.0))
    index: npt.NDArray[np.int64] = np.minimum(
        (level * len(PALETTE)).astype(np.int64), len(PALETTE) - 1
    )
    return index


def heat_rows(grid: np.ndarray, lines: int = MAP_LINES, width: int = MAP_WIDTH) -> list[str]:
    """``lines`` strings of ``width`` characters: the grid resampled to (2 * lines, width)
    cells, two cells a character (upper half block: foreground above, background below),
    so a cell is about square on a terminal. A colour is sent only where it changes."""
    rows, cols = grid.shape
    r = np.arange(2 * lines) * rows // (2 * lines)
    c = np.arange(width) * cols // width
    index = _levels(grid)[np.ix_(r, c)]
    out = []
    for top, bottom in zip(index[0::2], index[1::2], strict=True):
        line, last = [], None
        for pair in zip(top, bottom, strict=True):
            if pair != last:
                line.append(f"\x1b[38;5;{PALETTE[pair[0]]};48;5;{PALETTE[pair[1]]}m")
                last = pair
            line.append("▀")
        out.append("".join(line) + RESET)
    return out


def scale_row(cells: int = 16) -> str:
    """The colour key under the maps: the ramp from 0 to full scale, labelled in counts.

    The maps use a square-root scale (light loads stay visible), so the middle of the
    ramp is a quarter of full scale.
    """
    index = _levels(np.linspace(0.0, MAX_COUNT, cells))
    ramp = "".join(f"\x1b[48;5;{PALETTE[i]}m " for i in index) + RESET
    quarter = round(MAX_COUNT / 4)
    return f"  0 {ramp} {MAX_COUNT} counts, square-root scale (mid-ramp {quarter})"


def bar(fraction: float, width: int = BAR_WIDTH) -> str:
    filled = round(max(0.0, min(1.0, fraction)) * width)
    return "█" * filled + "░" * (width - filled)


_ESCAPE: Final = re.compile(r"\x1b\[[0-9;?]*[A-Za-z]")


def visible(text: str) -> str:
    """``text`` as the terminal shows it: escape codes taken out."""
    return _ESCAPE.sub("", text)


def render(state: ViewState, width: int = WIDTH) -> str:
    """The full screen: at most ``HEIGHT`` lines of at most ``width`` visible columns."""
    left = [_header(state, width), ""]
    feet = _feet(state.latest.get("pressure"))
    side = _probabilities(state.latest.get("action"))
    rows = max(len(feet), len(side))
    feet += [""] * (rows - len(feet))
    side += [""] * (rows - len(side))
    for foot_line, side_line in zip(feet, side, strict=True):
        pad = " " * max(0, FEET_WIDTH - len(visible(foot_line)))
        left.append(foot_line + pad + side_line)
    left.append(_action(state.latest.get("action")))
    left.append(_progress(state.latest.get("progress")))
    left.append(_latency(state))
    return "\n".join(_clip(line, width) for line in left[:HEIGHT])


def _clip(line: str, width: int) -> str:
    """``line`` cut to ``width`` visible columns (a line with colours is built to fit)."""
    return line if "\x1b" in line else line[:width]


def _header(state: ViewState, width: int) -> str:
    status = state.latest.get("status", {})
    st = status.get("state", "waiting")
    colour = {"online": 32, "degraded": 33, "offline": 31}.get(st, 37)
    where = state.topic or "waiting for the daemon"
    head = f"SCOTTI  {where}   status "
    reasons = ", ".join(status.get("reasons", []))
    room = width - len(head) - len(st) - 3
    if reasons and room > 3:
        reasons = f" ({reasons[: room - 1]}…)" if len(reasons) > room else f" ({reasons})"
    else:
        reasons = ""
    return f"{head}\x1b[{colour}m{st}{RESET}{reasons}"


def _feet(pressure: dict[str, Any] | None) -> list[str]:
    if pressure is None:
        return ["  (no pressure frames: the daemon publishes them with --pressure)"]
    left, right = pressure_grid(pressure, "left"), pressure_grid(pressure, "right")
    if left is None or right is None:
        return ["  (pressure frame unreadable)"]
    out = ["  left" + " " * (MAP_WIDTH - 4) + "  right"]
    out += [f"  {a}  {b}" for a, b in zip(heat_rows(left), heat_rows(right), strict=True)]
    out.append(scale_row())
    return out


def _probabilities(action: dict[str, Any] | None) -> list[str]:
    """The column beside the maps: every action's probability, most likely first."""
    if action is None:
        return []
    out = ["  " + "probabilities".ljust(NAME_WIDTH)]
    for act, p in sorted(action.get("probabilities", {}).items(), key=lambda kv: -kv[1]):
        out.append(f"  {act[:NAME_WIDTH]:<{NAME_WIDTH}} {bar(p, PROB_BAR)} {p:4.2f}")
    return out


def _action(action: dict[str, Any] | None) -> str:
    if action is None:
        return "action    (waiting)"
    name = action.get("action") or (
        f"withheld: {action['withheld']}" if action.get("withheld") else "none"
    )
    return f"action    \x1b[1m{name}\x1b[0m  confidence {action.get('confidence', 0.0):.2f}"


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
    """The payload's ``latency_ms`` (frame's last byte in -> handed to the client) and
    health's p99 of the same, ``end_to_end`` (docs/mqtt.md)."""
    pose = state.latest.get("pose", {})
    health = state.latest.get("health", {})
    p99 = health.get("end_to_end", {}).get("p99_ms")
    text = f"latency   {pose.get('latency_ms', float('nan')):5.1f} ms"
    if p99 is not None:
        text += f", p99 {p99:.1f} ms"
    text += f"   seq {pose.get('seq', '-')}   {state.rate_hz:4.1f} frames/s"
    if health:
        text += f"   dropped {health.get('dropped', 0)}"
    return text


def plain_line(state: ViewState) -> str:
    """One line of what arrived, no escape codes: the view when stdout is no terminal."""
    status = state.latest.get("status", {})
    reasons = ", ".join(status.get("reasons", []))
    parts = [
        state.topic or "waiting for the daemon",
        f"status {status.get('state', 'waiting')}" + (f" ({reasons})" if reasons else ""),
    ]
    pose = state.latest.get("pose")
    if pose is not None:
        parts.append(f"seq {pose.get('seq')}")
    action = state.latest.get("action")
    if action is not None:
        name = action.get("action") or f"withheld: {action.get('withheld') or 'none'}"
        parts.append(f"action {name} {action.get('confidence', 0.0):.2f}")
    progress = state.latest.get("progress")
    if progress is not None and progress.get("progress") is not None:
        parts.append(f"progress {progress['progress']:.2f} rep {progress.get('repetition')}")
    if pose is not None:
        parts.append(f"latency {pose.get('latency_ms', float('nan')):.1f} ms")
        parts.append(f"{state.rate_hz:.1f} frames/s")
    return "  ".join(parts)


async def run_viewer(
    settings: MqttSettings,
    stop: asyncio.Event,
    *,
    device: str = "+",
    out: TextIO = sys.stdout,
    fps: float = 8.0,
    state: ViewState | None = None,
    plain: bool | None = None,
) -> ViewState:
    """Subscribe and draw until ``stop``; reconnects while the broker is away.

    ``state``: the caller's own, to watch while the view runs (the demo waits
    for its first frame); a fresh one when None. ``plain``: one line a second
    without escape codes; None: when ``out`` is not a terminal.
    """
    state = ViewState() if state is None else state
    if plain is None:
        plain = not out.isatty()
    draw = _print_lines(state, stop, out) if plain else _draw(state, stop, out, fps)
    drawer = asyncio.create_task(draw)
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


async def _print_lines(state: ViewState, stop: asyncio.Event, out: TextIO) -> None:
    """A plain line every ``PLAIN_EVERY_S`` while something new arrived, and at the end."""
    said = None
    while True:
        stopping = await wait_event(stop, PLAIN_EVERY_S)
        line = plain_line(state)
        if line != said or state.rate_hz:
            out.write(line + "\n")
            out.flush()
            said = line
        if stopping:
            return


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m scotti.daemon.tools.viewer")
    parser.add_argument("--broker", default="mqtt://localhost:1883")
    parser.add_argument("--topic-prefix", default="scotti")
    parser.add_argument("--device", default="+", help="device id (default: any)")
    parser.add_argument("--duration", type=float, default=0, help="seconds, 0 = until Ctrl-C")
    parser.add_argument(
        "--plain",
        action="store_true",
        help="one plain line a second, no escape codes (the default when stdout is not a terminal)",
    )
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
        await run_viewer(settings, stop, device=args.device, plain=args.plain or None)

    with contextlib.suppress(KeyboardInterrupt):
        asyncio.run(go())
    return 0


if __name__ == "__main__":
    sys.exit(main())
