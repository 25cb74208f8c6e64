"""Serial-port fixtures: synthetic sessions and a board emulator on a real pty."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from scotti.daemon.input.board_emulator import BoardEmulator

from tests.support.sessions import SyntheticSession, write_synthetic_session


@pytest.fixture
def synthetic_session(tmp_path: Path) -> SyntheticSession:
    """32 frame pairs (2 s at 16 Hz), both feet, 4 row blocks per foot frame."""
    return write_synthetic_session(tmp_path / "synthetic.scotti")


@pytest.fixture
def board_factory(tmp_path: Path) -> Iterator[Callable[..., BoardEmulator]]:
    """Start a ``BoardEmulator`` on a pty linked at ``tmp_path/ttyBOARDn``; stopped at teardown.

    Call it with a session path (or records) and the emulator's keyword arguments.
    """
    started: list[BoardEmulator] = []

    def make(
        source: Path | SyntheticSession | list[tuple[int, bytes]], **kwargs: Any
    ) -> BoardEmulator:
        link = kwargs.pop("link", tmp_path / f"ttyBOARD{len(started)}")
        if isinstance(source, SyntheticSession):
            emulator = BoardEmulator(source.records, link, **kwargs)
        elif isinstance(source, Path):
            emulator = BoardEmulator.from_session(source, link, **kwargs)
        else:
            emulator = BoardEmulator(source, link, **kwargs)
        emulator.start()
        started.append(emulator)
        return emulator

    yield make
    for emulator in started:
        emulator.stop()
