"""The no-hardware source: a simulated scene played by the board emulator on a pty.

The scene is rendered to a temporary session file by the simulator (the same
writer that makes training data), the board emulator plays that file into a
pseudo-terminal, and the bytes are read back through ``SerialSource``: the
demo exercises every part of the live path, the serial port included.
"""

from __future__ import annotations

import asyncio
import contextlib
import tempfile
from collections.abc import AsyncGenerator, AsyncIterator
from importlib import resources
from pathlib import Path

from scotti.daemon.input.board_emulator import BoardEmulator
from scotti.daemon.input.sources import SerialSource, SourceError, SourceEvent, SourceItem
from scotti.daemon.input.speed import Speed
from scotti.daemon.waiting import Backoff


def resolve_scene(scene: str | Path) -> Path:
    """A scene TOML path, or the name of one shipped in ``sim/scenes`` (``demo``)."""
    path = Path(scene)
    if path.is_file():
        return path
    shipped = resources.files("scotti.sim") / "scenes" / f"{scene}.toml"
    if shipped.is_file():
        return Path(str(shipped))
    msg = f"scene {scene!r}: no such file and no shipped scene of that name"
    raise SourceError(msg)


def check_scene(scene_path: Path) -> None:
    """Parse and validate a scene now, so a broken one stops the daemon at start."""
    from scotti.sim import SimError
    from scotti.sim.scene import load_scene

    try:
        load_scene(scene_path)
    except SimError as exc:
        raise SourceError(str(exc)) from None


def render_scene_file(scene_path: Path, session_path: Path) -> None:
    """Render a scene into a session file (runs in a worker thread: it takes seconds)."""
    from scotti.sim import SimError
    from scotti.sim.corpus import render_scene
    from scotti.sim.scene import load_scene

    try:
        render_scene(load_scene(scene_path), session_path)
    except SimError as exc:
        raise SourceError(str(exc)) from None


class SimulatedSource:
    """A scene, rendered once, played by a board emulator on a pty: in a loop (its
    sequence numbers and clock going on across loops, as one long session), or once
    (``loop=False``: the stream ends once the board has played it and it was read)."""

    live = True

    def __init__(
        self,
        scene: str | Path,
        *,
        speed: Speed = 1.0,
        loop: bool = True,
        stall_s: float = 0.5,
        backoff: Backoff | None = None,
    ) -> None:
        self.scene = scene
        # Resolved and validated here, not when streaming starts: an unknown or
        # broken scene is a one-line error at start, like any other bad setting.
        self.scene_path = resolve_scene(scene)
        check_scene(self.scene_path)
        self.speed = speed
        self.loop = loop
        self.stall_s = stall_s
        self.backoff = backoff
        self.name = f"simulated {Path(scene).stem}"
        self.emulator: BoardEmulator | None = None  # while streaming, for tests and demos

    def __aiter__(self) -> AsyncIterator[SourceItem]:
        return self.stream()

    async def stream(self) -> AsyncGenerator[SourceItem, None]:
        scene_path = self.scene_path
        with tempfile.TemporaryDirectory(prefix="scotti-sim-") as tmp:
            session = Path(tmp) / "scene.scotti"
            yield SourceEvent("disconnected", f"rendering scene {scene_path.stem}")
            await asyncio.to_thread(render_scene_file, scene_path, session)
            emulator = await asyncio.to_thread(  # reads the session (and a loop's steps)
                BoardEmulator.from_session,
                session,
                Path(tmp) / "board",
                speed=self.speed,
                loop=self.loop,
            )
            emulator.start()
            self.emulator = emulator
            try:
                serial = SerialSource(
                    str(emulator.link),
                    stall_s=self.stall_s,
                    backoff=self.backoff,
                    played=None if self.loop else emulator.finished,
                )
                async with contextlib.aclosing(serial.stream()) as items:
                    async for item in items:
                        yield item
            finally:
                self.emulator = None
                await asyncio.to_thread(emulator.stop)
