"""The outputs from the daemon itself: ``scotti-daemon --record-mcap`` beside MQTT
(a real mosquitto) gives the same predictions on both; the flags' settings and
their one-line errors."""

from __future__ import annotations

import json
import logging
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from scotti.daemon.main import build_parser, cli_overrides, main
from scotti.daemon.settings import load_settings
from scotti.daemon.tools.local_broker import Mosquitto

from tests.support.broker import collect, payloads, start_daemon
from tests.support.sessions import write_synthetic_session

mcap_reader = pytest.importorskip("mcap.reader")
pytest.importorskip("foxglove")


def _mcap_json(path: Path, topic: str) -> list[dict[str, Any]]:
    with path.open("rb") as f:
        reader = mcap_reader.make_reader(f)
        return [json.loads(m.data) for _, _, m in reader.iter_messages(topics=[topic])]


@pytest.mark.mosquitto
def test_record_mcap_beside_mqtt(
    mosquitto: Mosquitto, tiny_model_path: Path, tmp_path: Path
) -> None:
    session = write_synthetic_session(tmp_path / "s.scotti", frames=60)
    out = tmp_path / "live.mcap"
    out.write_bytes(b"an older recording")  # never overwritten: a new name beside it
    device = "mcapdev"
    with collect(mosquitto, f"scotti/{device}/#") as got:
        args = ["--replay", str(session.path), "--speed", "8", "--model", str(tiny_model_path)]
        args += ["--broker", mosquitto.url, "--device-id", device, "--record-mcap", str(out)]
        daemon = start_daemon(args, tmp_path / "d.log")
        assert daemon.wait(60) == 0, daemon.log
        got.wait_for(
            lambda m: any(s["state"] == "offline" for s in payloads(m, "status")), 5, "offline"
        )
    assert out.read_bytes() == b"an older recording"
    (written,) = [p for p in tmp_path.glob("live.*.mcap")]
    mqtt = {a["seq"]: a["probabilities"] for a in payloads(got.snapshot(), "action")}
    mcap = {a["seq"]: a["probabilities"] for a in _mcap_json(written, "/action")}
    assert mqtt
    # MQTT may drop the oldest under load (its queue is bounded); what it has, the file
    # has, the same to the last digit.
    assert set(mqtt) <= set(mcap)
    assert {seq: mcap[seq] for seq in mqtt} == mqtt
    states = [s["state"] for s in _mcap_json(written, "/status")]
    assert states[-1] == "offline"
    assert "online" in states


def test_output_flags_become_settings(tmp_path: Path) -> None:
    args = build_parser().parse_args(
        ["--port", "/dev/null", "--foxglove", "--lsl", "--web", "8080", "--record-mcap", "x.mcap"]
    )
    outputs = load_settings(cli_overrides(args)).outputs
    assert outputs.foxglove == 8765  # Foxglove's own default port when none is given
    assert outputs.lsl
    assert outputs.web == 8080
    assert outputs.record_mcap == Path("x.mcap")
    assert load_settings({"source": {"port": "/dev/null"}}).outputs.any is False


@pytest.fixture
def root_logging() -> Iterator[None]:
    """main() points the root logger at this test's captured stderr; give it back after,
    or later tests log into a closed stream."""
    handlers, level = logging.root.handlers[:], logging.root.level
    yield
    logging.root.handlers[:] = handlers
    logging.root.setLevel(level)


@pytest.mark.usefixtures("root_logging")
def test_a_busy_web_port_is_one_line(
    tmp_path: Path, tiny_model_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import socket

    session = write_synthetic_session(tmp_path / "s.scotti", frames=4)
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        code = main(["--replay", str(session.path), "--model", str(tiny_model_path),
                     "--broker", "mqtt://127.0.0.1:1", "--web", str(port)])  # fmt: skip
    assert code == 78
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith(f"scotti-daemon: error: --web: cannot listen on 127.0.0.1:{port}")


def test_the_daemon_core_does_not_load_the_output_libraries() -> None:
    import subprocess
    import sys

    code = (
        "import sys, scotti.daemon.app, scotti.daemon.main;"
        "print(sorted(m for m in ('foxglove', 'mcap', 'pylsl') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_a_missing_library_names_the_extra() -> None:
    from scotti.daemon.outputs import OutputError, require

    with pytest.raises(OutputError, match=r"^--lsl needs the Python package 'no_such_lib_x'"):
        require("no_such_lib_x", "--lsl")
    with pytest.raises(OutputError, match=r"pip install 'scotti\[outputs\]'$"):
        require("no_such_lib_x", "--lsl")
