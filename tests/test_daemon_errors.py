"""One exception root for the daemon: every error it raises is a ``DaemonError``."""

from __future__ import annotations

import importlib
import inspect
import pkgutil
import subprocess
import sys
from pathlib import Path

import scotti.daemon
from scotti.daemon.errors import DaemonError

from tests.support.sessions import SyntheticSession


def daemon_exception_classes() -> list[type[BaseException]]:
    found: list[type[BaseException]] = []
    for module in pkgutil.walk_packages(scotti.daemon.__path__, "scotti.daemon."):
        if module.name.startswith("scotti.daemon.tools"):
            continue  # the tools around the service raise their own
        mod = importlib.import_module(module.name)
        for _, obj in inspect.getmembers(mod, inspect.isclass):
            if issubclass(obj, BaseException) and obj.__module__ == mod.__name__:
                found.append(obj)
    return found


def test_every_daemon_exception_derives_from_daemon_error() -> None:
    classes = daemon_exception_classes()
    names = {f"{c.__module__}.{c.__qualname__}" for c in classes}
    assert {
        "scotti.daemon.settings.checks.ConfigError",
        "scotti.daemon.input.sources.SourceError",
        "scotti.daemon.input.recording.RecordingError",
        "scotti.daemon.input.board_emulator.EmulatorError",
    } <= names
    stray = sorted(
        n
        for c in classes
        if not issubclass(c, DaemonError)
        for n in [f"{c.__module__}.{c.__qualname__}"]
    )
    assert stray == []


def test_a_recording_that_cannot_start_is_one_line_and_exit_78(
    tmp_path: Path, tiny_model_path: Path, synthetic_session: SyntheticSession
) -> None:
    session = synthetic_session.path
    exe = Path(sys.executable).with_name("scotti-daemon")
    result = subprocess.run(
        [
            str(exe),
            "--replay",
            str(session),
            "--model",
            str(tiny_model_path),
            "--broker",
            "mqtt://127.0.0.1:1",
            "--record",
            str(tmp_path / "no" / "dir.scotti"),
        ],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert result.returncode == 78
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert "cannot create session file" in lines[0]
