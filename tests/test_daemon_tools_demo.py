"""The terminal view, the optional pressure topic it draws, and the demo end to end."""

from __future__ import annotations

import asyncio
import base64
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from scotti.daemon.mqtt.messages import downsample
from scotti.daemon.mqtt.schemas import Pressure
from scotti.daemon.tools.local_broker import Mosquitto
from scotti.daemon.tools.viewer import (
    ViewState,
    decode_payload,
    plain_line,
    pressure_grid,
    render,
    visible,
)
from scotti.firmware_protocol.packets import Foot
from scotti.models.contract import ACTIONS

from tests.support.broker import collect, start_daemon
from tests.support.sessions import synthetic_counts, write_synthetic_session


def grid_bytes(grid: np.ndarray) -> str:
    return base64.urlsafe_b64encode(grid.astype("<u2").tobytes()).decode()


def test_render_shows_feet_action_progress_and_latency() -> None:
    state = ViewState()
    left = np.full((16, 11), 4095, dtype=np.uint16)
    right = np.zeros((16, 11), dtype=np.uint16)
    state.update("status", {"state": "degraded", "reasons": ["right insole silent"]}, "s/d/status")
    state.update("pose", {"seq": 41, "latency_ms": 3.25}, "scotti/dev/pose")
    state.update(
        "action",
        {"action": "squat", "confidence": 0.87, "probabilities": {"squat": 0.87, "jump": 0.13}},
        "scotti/dev/action",
    )
    state.update(
        "progress",
        {"action": "squat", "progress": 0.5, "repetition": 3},
        "scotti/dev/progress",
    )
    state.update(
        "pressure",
        {"rows": 16, "cols": 11, "left": grid_bytes(left), "right": grid_bytes(right)},
        "scotti/dev/pressure",
    )
    screen = render(state)
    assert "scotti/dev" in screen
    assert "degraded" in screen
    assert "right insole silent" in screen
    assert "squat" in screen
    assert "0.87" in screen
    assert "█" * 15 + "░" * 15 in screen  # progress 0.5 of a 30-wide bar
    assert "rep 3" in screen
    assert "3.2 ms" in screen or "3.3 ms" in screen
    # Left foot all hot, right all cold: one colour (upper and lower half) per map line,
    # sent once at its start; and each end of the ramp once in the colour key.
    assert screen.count("\x1b[38;5;196;48;5;196m" + "▀" * 22) == 16
    assert screen.count("\x1b[38;5;16;48;5;16m" + "▀" * 22) == 16
    assert "0 \x1b[48;5;16m" in screen
    assert "\x1b[48;5;196m \x1b[0m 4095 counts" in screen


def test_render_shows_standing_without_a_progress_bar() -> None:
    state = ViewState()
    state.update(
        "action",
        {"action": "standing", "confidence": 0.95, "probabilities": {"standing": 0.95}},
        "scotti/dev/action",
    )
    state.update(
        "progress",
        {"action": "standing", "progress": None, "repetition": -1},
        "scotti/dev/progress",
    )
    screen = render(state)
    progress_line = next(line for line in screen.splitlines() if line.startswith("progress"))
    assert progress_line == "progress  (standing: no repetition running)"
    assert "█" not in progress_line
    assert "░" not in progress_line
    assert "rep" not in progress_line.replace("repetition", "")


def busy_state(rows: int, cols: int) -> ViewState:
    """Everything at once: long reasons, all nine actions, a full pressure frame."""
    state = ViewState()
    reasons = ["right insole silent", "unfamiliar: input unlike the training data", "x" * 90]
    state.update("status", {"state": "degraded", "reasons": reasons}, "scotti/a-long-id/status")
    state.update("pose", {"seq": 123456, "latency_ms": 1234.5}, "scotti/a-long-id/pose")
    probabilities = {a: 1 / len(ACTIONS) for a in ACTIONS}
    action = {"action": "backward_walking", "confidence": 0.99, "probabilities": probabilities}
    state.update("action", action, "scotti/a-long-id/action")
    progress = {"action": "in_place_walking", "progress": 0.99, "repetition": 1234}
    state.update("progress", progress, "scotti/a-long-id/progress")
    state.update("health", {"end_to_end": {"p99_ms": 9999.9}, "dropped": 10**9}, "s/d/health")
    grid = grid_bytes(np.arange(rows * cols).reshape(rows, cols) % 4096)
    pressure = {"rows": rows, "cols": cols, "left": grid, "right": grid}
    state.update("pressure", pressure, "scotti/a-long-id/pressure")
    return state


@pytest.mark.parametrize(("rows", "cols"), [(32, 22), (16, 11), (8, 6), (4, 3)])
def test_the_view_fits_80_columns_by_24_lines(rows: int, cols: int) -> None:
    for state in (busy_state(rows, cols), ViewState()):
        lines = render(state).split("\n")
        assert len(lines) <= 24
        assert max(len(visible(line)) for line in lines) <= 80
        maps = [line for line in lines if "▀" in line]
        assert len(maps) in (0, 16)


def test_the_plain_line_has_no_escape_codes() -> None:
    line = plain_line(busy_state(16, 11))
    assert "\x1b" not in line
    assert "\n" not in line
    assert "status degraded (right insole silent" in line
    assert "seq 123456" in line
    assert "action backward_walking 0.99" in line
    assert "progress 0.99 rep 1234" in line


def test_render_before_anything_arrived() -> None:
    screen = render(ViewState())
    assert "waiting" in screen
    assert "no pressure frames" in screen


def test_decode_by_content_type() -> None:
    import msgpack

    assert decode_payload(b'{"a": 1}', "application/json") == {"a": 1}
    assert decode_payload(msgpack.packb({"a": 1}), "application/msgpack") == {"a": 1}
    assert decode_payload(b"\xff garbage", None) is None


def test_downsample_means_blocks() -> None:
    counts = np.arange(32 * 22, dtype=np.uint16).reshape(32, 22)
    small = downsample(counts, 2)
    assert small.shape == (16, 11)
    assert small[0, 0] == round((0 + 1 + 22 + 23) / 4)
    assert downsample(counts, 1).tolist() == counts.tolist()
    assert downsample(counts, 3).shape == (11, 8)  # edges padded


def test_pressure_payload_is_the_prediction_input_frame(
    tmp_path: Path, tiny_model_path: Path
) -> None:
    """At downsample 1 the payload is exactly the frame that made the prediction."""
    from scotti.daemon.frames.pipeline import Pipeline, Prediction
    from scotti.daemon.input.sources import ReplaySource
    from scotti.daemon.mqtt.messages import frame_payloads
    from scotti.daemon.service.counters import Counters
    from scotti.models.runtime import ScottiRuntime

    session = write_synthetic_session(tmp_path / "p1.scotti", frames=44)
    predictions: list[Prediction] = []
    pipeline = Pipeline(
        ReplaySource(session.path, speed="max"), ScottiRuntime(tiny_model_path), Counters()
    )
    asyncio.run(pipeline.run(predictions.append, lambda _: None, asyncio.Event()))
    assert len(predictions) == 44 - 39
    for prediction in predictions:
        topics = dict(frame_payloads(prediction, 1.0, pressure_downsample=1))
        assert set(topics) == {"pose", "action", "progress", "pressure"}
        p = topics["pressure"]
        assert isinstance(p, Pressure)
        assert (p.rows, p.cols, p.downsample) == (32, 22, 1)
        left = np.frombuffer(p.left, "<u2").reshape(32, 22)
        right = np.frombuffer(p.right, "<u2").reshape(32, 22)
        np.testing.assert_array_equal(left, synthetic_counts(Foot.LEFT, p.device_seq.left))
        np.testing.assert_array_equal(right, synthetic_counts(Foot.RIGHT, p.device_seq.right))
        np.testing.assert_array_equal(np.hstack([left, right]), prediction.counts)
    assert "pressure" not in dict(frame_payloads(predictions[0], 1.0))


@pytest.mark.mosquitto
@pytest.mark.slow
def test_pressure_topic_carries_the_downsampled_frames(
    mosquitto: Mosquitto, tiny_model_path: Path, tmp_path: Path
) -> None:
    session = write_synthetic_session(tmp_path / "p.scotti", frames=48)
    with collect(mosquitto, "scotti/press/#") as got:
        args = ["--replay", str(session.path), "--speed", "8", "--model", str(tiny_model_path)]
        args += ["--broker", mosquitto.url, "--device-id", "press", "--pressure"]
        daemon = start_daemon(args, tmp_path / "press.log", env={"SCOTTI_MQTT_FORMAT": "msgpack"})
        assert daemon.wait(60) == 0, daemon.log
        got.wait_for(lambda m: any(x.topic.endswith("/status") for x in m), 5)
    msgs = [m for m in got.snapshot() if m.topic.endswith("/pressure")]
    assert len(msgs) == 48 - 39
    assert all(m.content_type == "application/msgpack" for m in msgs)
    import msgpack

    p = Pressure.model_validate(msgpack.unpackb(msgs[0].payload))
    assert (p.rows, p.cols, p.downsample) == (16, 11, 2)
    left = np.frombuffer(p.left, "<u2").reshape(16, 11)
    expected = downsample(synthetic_counts(Foot.LEFT, p.device_seq.left), 2)
    np.testing.assert_array_equal(left, expected)
    right = np.frombuffer(p.right, "<u2").reshape(16, 11)
    expected = downsample(synthetic_counts(Foot.RIGHT, p.device_seq.right), 2)
    np.testing.assert_array_equal(right, expected)
    assert pressure_grid(msgpack.unpackb(msgs[0].payload), "right") is not None


def demo_command(model: Path, duration: float) -> list[str]:
    demo = [sys.executable, "-m", "scotti.daemon.tools.demo", "--duration", str(duration)]
    return [*demo, "--speed", "2", "--model", str(model)]


def clean_env() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if not k.startswith("SCOTTI_")}


@pytest.mark.mosquitto
@pytest.mark.slow
def test_demo_on_a_terminal_draws_80_by_24_and_ends_cleanly(tiny_model_path: Path) -> None:
    import pty

    leader, follower = pty.openpty()
    with subprocess.Popen(
        demo_command(tiny_model_path, 6),
        stdin=subprocess.DEVNULL,
        stdout=follower,
        stderr=subprocess.PIPE,
        env=clean_env(),
    ) as proc:
        os.close(follower)
        chunks = []
        while True:
            try:
                data = os.read(leader, 65536)
            except OSError:  # EIO: the demo closed the terminal
                break
            if not data:
                break
            chunks.append(data)
        os.close(leader)
        assert proc.wait(90) == 0, proc.stderr.read() if proc.stderr else ""
    out = b"".join(chunks).decode(errors="replace").replace("\r\n", "\n")
    assert "\x1b[38;5;" in out  # heat maps were drawn
    assert out.count("\x1b[?1049h") == out.count("\x1b[?1049l") == 1  # screen back
    screen, summary = out.split("\x1b[?1049h", 1)[1].rsplit("\x1b[?1049l", 1)
    frames = [f for f in screen.split("\x1b[H")[1:] if "progress" in f]
    assert len(frames) > 10
    for frame in frames:
        lines = visible(frame).split("\n")
        assert len(lines) <= 24
        assert max(len(line) for line in lines) <= 80
    assert summary.strip().startswith("demo: ")
    assert int(summary.split()[1]) > 20  # frames shown
    assert "daemon exit 0" in summary


@pytest.mark.mosquitto
@pytest.mark.slow
def test_demo_without_a_terminal_prints_plain_lines(tiny_model_path: Path) -> None:
    out = subprocess.run(
        demo_command(tiny_model_path, 3),
        capture_output=True,
        text=True,
        timeout=90,
        env=clean_env(),
    )
    assert out.returncode == 0, out.stderr + out.stdout[-2000:]
    assert "\x1b" not in out.stdout  # no escape codes in a pipe
    lines = out.stdout.strip().splitlines()
    assert any(" action " in line and " latency " in line for line in lines), lines
    assert lines[-1].startswith("demo: ")
    assert "daemon exit 0" in lines[-1]


def test_demo_with_an_unknown_scene_is_one_line(
    tiny_model_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from scotti.daemon.tools import demo

    assert demo.main(["--scene", "no-such-scene", "--model", str(tiny_model_path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["demo: scene 'no-such-scene': no such file and no shipped scene of that name"]


def test_demo_duration_counts_from_the_first_frame_shown() -> None:
    # Launch, broker, daemon and scene rendering take seconds (more on a busy
    # host); a --duration counted from launch once ended before any frame.
    from scotti.daemon.tools.demo import _stop_after_frames

    async def scenario() -> tuple[float, float]:
        state, stop = ViewState(), asyncio.Event()
        start = time.monotonic()
        timer = asyncio.create_task(_stop_after_frames(state, 0.3, stop))
        await asyncio.sleep(0.5)  # nothing shown yet: the clock has not started
        assert not stop.is_set()
        state.update("pose", {}, "scotti/demo/pose")
        shown = time.monotonic()
        await stop.wait()
        await timer
        return shown - start, time.monotonic() - shown

    before, after = asyncio.run(scenario())
    assert before >= 0.5
    assert after >= 0.3


def test_scripts_demo_runs_the_setup_only_when_something_changed(tmp_path: Path) -> None:
    """scripts/demo itself, in a copy of the repository whose scripts/setup only says it
    ran and makes a .venv whose python is this one."""
    import shutil

    repo = Path(__file__).parents[1]
    copy = tmp_path / "repo"
    (copy / "scripts").mkdir(parents=True)
    shutil.copy2(repo / "scripts" / "demo", copy / "scripts" / "demo")
    shutil.copy2(repo / "pyproject.toml", copy / "pyproject.toml")
    runs = tmp_path / "setup-runs"
    setup = copy / "scripts" / "setup"
    setup.write_text(
        "#!/usr/bin/env bash\nset -e\n"
        f'echo "$SCOTTI_EXTRAS" >> {runs}\n'
        "mkdir -p .venv/bin .venv/lib/python3.11/site-packages\n"
        f"printf '#!/bin/sh\\nexec {sys.executable} \"$@\"\\n' > .venv/bin/python\n"
        "chmod +x .venv/bin/python\n"
    )
    setup.chmod(0o755)

    def demo_help(**env: str) -> list[str]:
        out = subprocess.run(
            [str(copy / "scripts" / "demo"), "--help"],
            capture_output=True,
            text=True,
            timeout=60,
            env={**clean_env(), **env},
            check=True,
        )
        assert "usage: scripts/demo" in out.stdout
        return runs.read_text().split()

    assert demo_help() == ["demo"]  # the first start sets up
    assert demo_help() == ["demo"]  # nothing changed: no setup
    (copy / "pyproject.toml").write_text((copy / "pyproject.toml").read_text() + "\n# x\n")
    assert demo_help() == ["demo", "demo"]  # pyproject.toml changed
    assert demo_help(SCOTTI_EXTRAS="demo,outputs") == ["demo", "demo", "demo,outputs"]
    assert demo_help(SCOTTI_EXTRAS="demo,outputs") == ["demo", "demo", "demo,outputs"]
    time.sleep(0.05)
    (copy / ".venv" / "lib" / "python3.11" / "site-packages" / "new.pth").write_text("")
    assert demo_help() == ["demo", "demo", "demo,outputs", "demo"]  # the venv changed
    assert demo_help() == ["demo", "demo", "demo,outputs", "demo"]
