"""The outputs from the daemon itself: ``scotti-daemon --record-mcap`` beside MQTT
(a real mosquitto) gives the same predictions on both; two devices in one daemon
(real ptys), each with its own channels, outlets and page, the silent one holding up
nothing; the flags' settings and their one-line errors; the predictions an output that
falls behind never got, in the device's health; the outputs closed on every way out of
a run, a failure or a cancellation after the start included."""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import json
import logging
import re
import socket
import threading
import time
import urllib.request
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from scotti.daemon.frames.pipeline import Prediction
from scotti.daemon.inference.engine import InferenceEngine
from scotti.daemon.input.sources import ReplaySource
from scotti.daemon.mqtt import messages as payload
from scotti.daemon.mqtt.schemas import Status
from scotti.daemon.outputs import Outputs
from scotti.daemon.service.app import Daemon
from scotti.daemon.service.device import Device
from scotti.daemon.service.main import build_parser, cli_overrides, main
from scotti.daemon.settings import Settings, load_settings
from scotti.daemon.tools.local_broker import Mosquitto
from scotti.models.runtime import ScottiRuntime

from tests.support.broker import DaemonProcess, collect, payloads, start_daemon
from tests.support.foxglove_schema import misfits, problems
from tests.support.outputs import lsl_on_this_host, read_mcap
from tests.support.sessions import write_synthetic_session

lsl_on_this_host()  # the daemon's LSL outlets found here without multicast

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
    out = tmp_path / "live-{time}.mcap"  # a new file at every start, as a service wants
    device = "mcapdev"
    with collect(mosquitto, f"scotti/{device}/#") as got:
        args = ["--replay", str(session.path), "--speed", "8", "--model", str(tiny_model_path)]
        args += ["--broker", mosquitto.url, "--device-id", device, "--record-mcap", str(out)]
        daemon = start_daemon(args, tmp_path / "d.log")
        assert daemon.wait(60) == 0, daemon.log
        got.wait_for(
            lambda m: any(s["state"] == "offline" for s in payloads(m, "status")), 5, "offline"
        )
    (written,) = [p for p in tmp_path.glob("live-*.mcap")]
    assert re.fullmatch(r"live-\d{8}T\d{6}\.mcap", written.name), written.name
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
    # The file says what made it, as an export does: the model and the daemon's settings.
    messages, _, metadata = read_mcap(written)
    (made_by,) = [m.metadata for m in metadata if m.name == "scotti"]
    assert made_by["model"] == tiny_model_path.name
    assert made_by["model_sha256"] == hashlib.sha256(tiny_model_path.read_bytes()).hexdigest()
    assert made_by["source"] == "live"
    assert made_by["devices"] == device
    config = json.loads(made_by["config"])
    assert config["mqtt"]["device_id"] == device
    assert config["outputs"]["record_mcap"] == str(out)
    assert config["mqtt"]["password_set"] is False  # the settings as ``info`` has them
    # Every JSON channel's schema is one Foxglove's parser reads, and its messages fit it.
    with written.open("rb") as f:
        summary = mcap_reader.make_reader(f).get_summary()
    assert summary is not None
    json_topics = set()
    for channel in summary.channels.values():
        if channel.message_encoding == "json":
            schema = json.loads(summary.schemas[channel.schema_id].data)
            assert problems(schema) == [], channel.topic
            assert all(misfits(m, schema) == [] for _, m in messages[channel.topic])
            json_topics.add(channel.topic)
    assert json_topics == {"/pose", "/action", "/progress", "/status"}


@pytest.mark.usefixtures("root_logging")
def test_a_fixed_mcap_name_that_exists_stops_the_start_with_the_hint(
    tmp_path: Path, tiny_model_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    session = write_synthetic_session(tmp_path / "s.scotti", frames=4)
    out = tmp_path / "live.mcap"
    out.write_bytes(b"yesterday's recording")
    code = main(["--replay", str(session.path), "--model", str(tiny_model_path),
                 "--broker", "mqtt://127.0.0.1:1", "--record-mcap", str(out)])  # fmt: skip
    assert code == 78
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == (
        f"scotti-daemon: error: --record-mcap: {out} exists and is never overwritten; for a "
        f"new file at every start put {{time}} in the name ({tmp_path / 'live-{time}.mcap'}) "
        "or give a directory, else move the file away"
    )
    assert out.read_bytes() == b"yesterday's recording"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["live.mcap", "s.scotti"]


def _wait_log(daemon: DaemonProcess, pattern: str, timeout: float) -> re.Match[str]:
    deadline = time.monotonic() + timeout
    while (found := re.search(pattern, daemon.log)) is None:
        assert daemon.proc.poll() is None, daemon.log[-3000:]
        assert time.monotonic() < deadline, f"no {pattern!r} in the log:\n{daemon.log[-3000:]}"
        time.sleep(0.1)
    return found


def _feed_frames(url: str, count: int) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """The hello and the first ``count`` frames of an SSE feed."""
    frames: list[dict[str, Any]] = []
    with urllib.request.urlopen(url, timeout=10) as feed:
        hello = json.loads(feed.readline().removeprefix(b"data: "))
        while len(frames) < count:
            line = feed.readline()
            assert line, "the feed ended"
            if line.startswith(b"data: "):
                event = json.loads(line.removeprefix(b"data: "))
                if event["type"] == "frame":
                    frames.append(event)
    return hello, frames


@pytest.mark.mosquitto
def test_two_devices_in_one_daemon_each_on_its_own_channels_the_silent_one_holds_up_nothing(
    mosquitto: Mosquitto, tiny_model_path: Path, tmp_path: Path, board_factory: Callable[..., Any]
) -> None:
    pylsl = pytest.importorskip("pylsl")
    from scotti.daemon.tools.bench import board_records

    records = board_records(4.0)
    live = board_factory(records, loop=True, link=tmp_path / "live")
    silent = board_factory(records, loop=True, link=tmp_path / "silent")
    silent.pause()  # plugged in, never a byte
    run = f"{time.monotonic_ns() % 10**8}"  # this run's LSL outlets, never another's
    live_id, silent_id = f"live{run}", f"silent{run}"
    config = tmp_path / "two.toml"
    config.write_text(
        f'log_level = "info"\n[mqtt]\nbroker = "{mosquitto.url}"\n'
        f'[[devices]]\nid = "{live_id}"\nport = "{live.link}"\n'
        f'[[devices]]\nid = "{silent_id}"\nport = "{silent.link}"\n'
        f'[outputs]\nrecord_mcap = "{tmp_path / "two.mcap"}"\nweb = 0\nlsl = true\n'
    )
    with collect(mosquitto, "scotti/#") as got:
        daemon = start_daemon(
            ["--config", str(config), "--model", str(tiny_model_path)], tmp_path / "d.log"
        )
        try:
            url = _wait_log(daemon, r"2 devices listed on (http://\S+/),", 30)[1]
            # The web: the live device's frames on its page's feed while the other is silent.
            hello, frames = _feed_frames(f"{url}devices/{live_id}/events", 5)
            assert (hello["device"], hello["devices"]) == (live_id, [live_id, silent_id])
            assert {f["device"] for f in frames} == {live_id}
            seqs = [f["seq"] for f in frames]
            assert seqs == sorted(seqs)
            with urllib.request.urlopen(f"{url}devices", timeout=5) as listing:
                listed = {d["id"]: d for d in json.load(listing)}
            assert listed[live_id]["view"] == f"/devices/{live_id}/"
            # LSL: four outlets per device; the live one's carry samples, the silent's none.
            inlets = {}
            for device in (live_id, silent_id):
                for what in ("pose", "action", "progress", "pressure"):
                    source = f"scotti/{device}/{what}"
                    (info,) = pylsl.resolve_byprop("source_id", source, 1, 10.0)
                    assert info.name() == f"{device} {what}"
                inlets[device] = pylsl.StreamInlet(info, max_buflen=60)
                inlets[device].open_stream(timeout=10.0)
            samples, _ = inlets[live_id].pull_chunk(timeout=5.0, max_samples=3)
            deadline = time.monotonic() + 5.0
            while len(samples) < 3 and time.monotonic() < deadline:
                more, _ = inlets[live_id].pull_chunk(timeout=1.0, max_samples=3)
                samples += more
            assert len(samples) >= 3
            assert inlets[silent_id].pull_chunk(timeout=0.5)[0] == []
            # MQTT is untouched by the outputs: the live device keeps publishing.
            got.wait_for(lambda m: len(payloads(m, "pose")) >= 5, 10, "poses")
        finally:
            assert daemon.stop() == 0, daemon.log[-3000:]
        mqtt = got.snapshot()
    # The MCAP file: one for the daemon, every topic under its device's id.
    (written,) = tmp_path.glob("two*.mcap")
    messages, schemas, metadata = read_mcap(written)
    assert all(t.startswith((f"/{live_id}/", f"/{silent_id}/")) for t in messages), messages.keys()
    live_actions = [m["seq"] for _, m in messages[f"/{live_id}/action"]]
    assert set(seqs) <= set(live_actions)
    mqtt_actions = {a["seq"] for a in payloads(mqtt, "action")}
    assert mqtt_actions <= set(live_actions)
    assert schemas[f"/{live_id}/skeleton"] == "foxglove.SceneUpdate"
    assert f"/{silent_id}/action" not in messages  # silent: no frame, no prediction
    for device in (live_id, silent_id):  # each ends with its own last word
        assert messages[f"/{device}/status"][-1][1]["state"] == "offline"
    (devices,) = [m for m in metadata if m.name == "scotti.devices"]
    assert devices.metadata == {live_id: f"/{live_id}/", silent_id: f"/{silent_id}/"}


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
        "import sys, scotti.daemon.service.app, scotti.daemon.service.main;"
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


def test_a_library_that_cannot_load_is_one_line(tmp_path: Path, tiny_model_path: Path) -> None:
    # pylsl installed without its liblsl raises RuntimeError (a long, multi-line one)
    # when imported, not ImportError: still one line and exit 78, never a traceback.
    broken = tmp_path / "site" / "pylsl"
    broken.mkdir(parents=True)
    (broken / "__init__.py").write_text(
        'raise RuntimeError("LSL binary library file was not found.\\n Install liblsl.")\n'
    )
    session = write_synthetic_session(tmp_path / "s.scotti", frames=4)
    args = ["--replay", str(session.path), "--model", str(tiny_model_path)]
    args += ["--broker", "mqtt://127.0.0.1:1", "--lsl"]
    daemon = start_daemon(args, tmp_path / "d.log", env={"PYTHONPATH": str(broken.parent)})
    assert daemon.wait(60) == 78, daemon.log
    assert "Traceback" not in daemon.log
    last = daemon.log.strip().splitlines()[-1]
    assert last == (
        "scotti-daemon: error: --lsl: the Python package 'pylsl' cannot be loaded: "
        "LSL binary library file was not found. Install liblsl."
    )


def _settings(args: list[str]) -> Settings:
    return load_settings(cli_overrides(build_parser().parse_args(args)))


class _HeldOutput:
    """An output that holds the outputs' thread until ``gate`` is set: it falls behind."""

    name = "held"

    def __init__(self) -> None:
        self.gate = threading.Event()
        self.predictions = 0

    def prediction(self, device: str, p: Prediction, latency_ms: float) -> None:
        self.gate.wait(30)
        self.predictions += 1

    def status(self, device: str, status: Status) -> None:
        self.gate.wait(30)

    async def close(self) -> None:
        self.gate.set()


def _replay_through(
    output: _HeldOutput,
    mosquitto: Mosquitto,
    model: Path,
    tmp_path: Path,
    device_id: str,
    frames: int,
) -> tuple[Device, Outputs, dict[str, Any]]:
    """One device as the daemon runs it (real replay at max speed, engine and broker),
    its predictions handed to ``output`` alone: the device and the outputs after both
    stopped, and the last ``health`` it published."""
    session = write_synthetic_session(tmp_path / "s.scotti", frames=frames)
    settings = _settings(["--replay", str(session.path), "--speed", "max",
                          "--broker", mosquitto.url, "--device-id", device_id])  # fmt: skip
    runtime = ScottiRuntime(model)

    async def run() -> tuple[Device, Outputs]:
        (one,) = settings.device_list()
        engine = InferenceEngine()
        source = ReplaySource(session.path, speed="max")
        device = Device(settings, one, runtime, engine, source, None)
        outputs = Outputs([output], [device.id])
        device.outputs = outputs.of(device.id)
        engine.start()
        try:
            assert await device.run(asyncio.Event(), payload.info(settings, runtime, {})) == 0
        finally:
            output.gate.set()
            await outputs.close()
            await engine.stop()
        return device, outputs

    with collect(mosquitto, f"scotti/{device_id}/health") as got:
        device, outputs = asyncio.run(run())
        made = device.counters.predictions
        final = got.wait_for(
            lambda m: any(h["predictions"] == made for h in payloads(m, "health")), 5, "health"
        )
    health = [h for h in payloads(final, "health") if h["predictions"] == made][-1]
    return device, outputs, health


@pytest.mark.mosquitto
def test_the_predictions_outputs_dropped_are_in_the_devices_health(
    mosquitto: Mosquitto, tiny_model_path: Path, tmp_path: Path
) -> None:
    # One device as the daemon runs it (real replay, engine and broker) with one output
    # that never keeps up, so the fan-out drops the oldest predictions.
    held = _HeldOutput()
    device, outputs, health = _replay_through(
        held, mosquitto, tiny_model_path, tmp_path, "outdrops", frames=100
    )
    made = device.counters.predictions
    assert outputs.dropped > 0  # it did fall behind
    assert health["pipeline"]["outputs"] == {
        "dropped_queue_full": outputs.dropped,
        "errors": {"held": 0},
    }
    assert held.predictions + outputs.dropped == made  # what the output never got


def _outputs_threads() -> set[threading.Thread]:
    return {t for t in threading.enumerate() if t.name == "scotti-outputs"}


def _assert_outputs_closed(mcap: Path, caplog: pytest.LogCaptureFixture) -> None:
    """The MCAP file is finished (readable to its end, its closing magic written), the
    web port no longer listens."""
    (written,) = mcap.parent.glob(f"{mcap.stem}*.mcap")
    assert written.read_bytes().endswith(b"\x89MCAP0\r\n"), "the MCAP file was left unfinished"
    read_mcap(written)
    (port,) = [
        int(m[1])
        for r in caplog.records
        if (m := re.search(r"web: live view on \S+:(\d+)/", r.getMessage()))
    ]
    with pytest.raises(ConnectionRefusedError), socket.create_connection(("127.0.0.1", port), 2):
        pass


def test_a_run_that_fails_after_opening_the_outputs_closes_them(
    tmp_path: Path, tiny_model_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # A loop outside the main thread cannot take signal handlers: ``run`` fails with its
    # own error right after it opened the outputs (the devices have not started).
    caplog.set_level(logging.INFO, logger="scotti.daemon.outputs")
    session = write_synthetic_session(tmp_path / "s.scotti", frames=4)
    out = tmp_path / "failed.mcap"
    settings = _settings(["--replay", str(session.path), "--model", str(tiny_model_path),
                          "--broker", "mqtt://127.0.0.1:1", "--record-mcap", str(out),
                          "--web", "0"])  # fmt: skip
    daemon = Daemon(settings, ScottiRuntime(tiny_model_path))
    before = _outputs_threads()
    raised: list[BaseException] = []

    def in_a_thread() -> None:
        try:
            asyncio.run(daemon.run())
        except BaseException as exc:
            raised.append(exc)

    thread = threading.Thread(target=in_a_thread)
    thread.start()
    thread.join(60)
    assert not thread.is_alive(), "the run did not end"
    (error,) = raised
    assert isinstance(error, RuntimeError)  # the run's own error, not one of the closing
    assert "main thread" in str(error)
    _assert_outputs_closed(out, caplog)
    assert not {t for t in _outputs_threads() - before if t.is_alive()}


@pytest.mark.mosquitto
def test_a_cancelled_run_closes_the_outputs_after_the_devices_last_word(
    mosquitto: Mosquitto, tiny_model_path: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, logger="scotti.daemon.outputs")
    session = write_synthetic_session(tmp_path / "s.scotti", frames=400)  # 25 s at speed 4
    out = tmp_path / "cancelled.mcap"
    settings = _settings(["--replay", str(session.path), "--speed", "4",
                          "--model", str(tiny_model_path), "--broker", mosquitto.url,
                          "--device-id", "cancelled", "--record-mcap", str(out),
                          "--web", "0"])  # fmt: skip
    daemon = Daemon(settings, ScottiRuntime(tiny_model_path))
    before = _outputs_threads()

    async def cancel_mid_run() -> None:
        run = asyncio.create_task(daemon.run())
        deadline = time.monotonic() + 30
        while daemon.counters.predictions < 3:
            assert not run.done(), "the run ended before it was cancelled"
            assert time.monotonic() < deadline, "no predictions"
            await asyncio.sleep(0.05)
        run.cancel()
        with pytest.raises(asyncio.CancelledError):  # the cancellation goes on, unmasked
            await run

    asyncio.run(cancel_mid_run())
    _assert_outputs_closed(out, caplog)
    assert not {t for t in _outputs_threads() - before if t.is_alive()}
    (written,) = tmp_path.glob("cancelled*.mcap")
    recorded, _, _ = read_mcap(written)
    assert recorded["/action"]  # it was recording when cancelled
    assert recorded["/status"][-1][1]["state"] == "offline"  # the device stopped first


class _FailingClose(_HeldOutput):
    name = "failing"

    async def close(self) -> None:
        msg = "this output cannot close"
        raise OSError(msg)


def test_an_output_that_fails_to_close_leaves_none_of_the_others_open(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    from scotti.daemon.outputs.foxglove_out import FoxgloveOutput

    mcap = FoxgloveOutput(mcap=tmp_path / "after.mcap", port=None, devices=["a"])
    failing = _FailingClose()
    failing.gate.set()
    outputs = Outputs([failing, mcap], ["a"])
    outputs.status("a", payload.status("online", [], None))
    asyncio.run(outputs.close())  # the failure is logged, not raised
    assert (tmp_path / "after.mcap").read_bytes().endswith(b"\x89MCAP0\r\n")
    assert [r.getMessage() for r in caplog.records if r.exc_info] == [
        "output failing did not close cleanly"
    ]


def test_devices_cancelled_at_the_stop_budget_finish_their_cleanup_first(
    tiny_model_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # A device that ignores the stop is cancelled when the budget runs out; its
    # cleanup (closing its port and client) must be over before ``_close`` closes
    # the engine and the outputs under it.
    settings = _settings(["--simulate", "demo", "--model", str(tiny_model_path)]).model_copy(
        update={"stop_timeout_s": 0.1}
    )  # budget 2 x 0.1 + 1 s
    daemon = Daemon(settings, ScottiRuntime(tiny_model_path))
    cleaned: list[str] = []

    async def deaf(name: str, cleanup_s: float) -> int:
        try:
            await asyncio.sleep(3600)  # never looks at the stop event
        except asyncio.CancelledError:
            await asyncio.sleep(cleanup_s)  # closing its port, its client
            cleaned.append(name)
            raise
        return 0

    async def stop() -> int:
        tasks = [asyncio.create_task(deaf(n, 0.3), name=n) for n in ("a", "b")]
        return await daemon._stop_devices(tasks)

    caplog.set_level(logging.WARNING, logger="scotti.daemon.service.app")
    assert asyncio.run(stop()) == 1
    assert sorted(cleaned) == ["a", "b"]  # both finished before _stop_devices returned
    assert "did not stop within 1.2 s" in caplog.text


def test_a_device_whose_cleanup_hangs_does_not_hang_the_stop(
    tiny_model_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    settings = _settings(["--simulate", "demo", "--model", str(tiny_model_path)]).model_copy(
        update={"stop_timeout_s": 0.1}
    )
    daemon = Daemon(settings, ScottiRuntime(tiny_model_path))

    async def fine() -> int:
        return 0

    released: list[bool] = []

    async def hangs() -> int:
        while not released:  # swallows every cancellation, until the test lets it go
            with contextlib.suppress(asyncio.CancelledError):
                await asyncio.sleep(3600)
        return 0

    async def stop() -> tuple[int, float]:
        tasks = [asyncio.create_task(fine(), name="ok"), asyncio.create_task(hangs(), name="hung")]
        started = time.monotonic()
        status = await asyncio.wait_for(daemon._stop_devices(tasks), 30)
        took = time.monotonic() - started
        released.append(True)  # let the loop end: the test's own cleanup
        tasks[1].cancel()
        await tasks[1]
        return status, took

    caplog.set_level(logging.WARNING, logger="scotti.daemon.service.app")
    status, took = asyncio.run(stop())
    assert status == 1
    assert took < 10  # the budget (1.2 s) and the grace (2 s), not the hang
    assert "still running 2.0 s after cancel: hung" in caplog.text


class _BrokenOutput(_HeldOutput):
    """An output whose every write fails (a disk gone, an outlet that raises)."""

    name = "broken"

    def prediction(self, device: str, p: Prediction, latency_ms: float) -> None:
        msg = "the disk is gone"
        raise OSError(msg)


@pytest.mark.mosquitto
def test_an_output_failing_on_every_prediction_is_counted_in_health(
    mosquitto: Mosquitto, tiny_model_path: Path, tmp_path: Path
) -> None:
    broken = _BrokenOutput()
    broken.gate.set()
    # The device runs to the end of its replay: a failing output stops nothing.
    device, outputs, health = _replay_through(
        broken, mosquitto, tiny_model_path, tmp_path, "outerrors", frames=60
    )
    made = device.counters.predictions
    assert made > 0
    # Health is built on the loop while the outputs' thread may still be writing:
    # what it says is counted, and by the end every prediction handed over failed.
    failed = health["pipeline"]["outputs"]["errors"]["broken"]
    assert 0 < failed <= outputs.errors["broken"]
    assert outputs.errors["broken"] + outputs.dropped == made


class _ServingOutput(_HeldOutput):
    """A network output as the web and Foxglove ones report themselves: its server's
    connections and refusals (``counters``), never holding anything up."""

    name = "web"

    def __init__(self) -> None:
        super().__init__()
        self.gate.set()
        self.counters = {"connections": 2, "max_connections": 64, "refused": {"over_cap": 5}}


@pytest.mark.mosquitto
def test_the_servers_connections_and_refusals_are_in_the_devices_health(
    mosquitto: Mosquitto, tiny_model_path: Path, tmp_path: Path
) -> None:
    serving = _ServingOutput()
    _, _, health = _replay_through(
        serving, mosquitto, tiny_model_path, tmp_path, "servers", frames=50
    )
    assert health["pipeline"]["outputs"]["servers"] == {"web": serving.counters}
    engine = health["pipeline"]["engine"]  # the engine's own counts beside them
    assert engine["frames"] >= 50 - 40
    assert engine["model_calls"] >= 1
