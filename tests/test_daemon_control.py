"""Remote control over MQTT against a real mosquitto: recording started and stopped by a
request (a session file ``scotti session info`` reads with the marked event, an MCAP
file with it too), the repetition count reset, replies on the MQTT v5 response topic with
the correlation data, bad requests answered and counted, a broker ACL that keeps
everyone else out, control off by default, and a flood that does not stop the poses."""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import AsyncIterator, Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import aiomqtt
import paho.mqtt.client as paho
import pytest
from paho.mqtt.enums import CallbackAPIVersion
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties
from scotti.daemon.frames.pipeline import Pipeline
from scotti.daemon.input.sources import ReplaySource
from scotti.daemon.mqtt.control import Control, mcap_missing
from scotti.daemon.mqtt.schemas import Event, Reply
from scotti.daemon.service.counters import Counters
from scotti.daemon.service.main import build_parser, cli_overrides, main
from scotti.daemon.settings import ConfigError, load_settings
from scotti.daemon.settings.mqtt import MqttSettings
from scotti.daemon.tools import control_flood
from scotti.daemon.tools.local_broker import Mosquitto
from scotti.firmware_protocol.session import (
    EventRecord,
    PacketRecord,
    SessionHeader,
    SessionWriter,
    iter_records,
    read_session,
)
from scotti.models.runtime import ScottiRuntime

from tests.support.broker import DaemonProcess, start_daemon
from tests.support.sessions import write_synthetic_session

SECONDS = 40  # of insole frames replayed at 16 Hz: longer than any test here needs
READY = "remote control: taking requests on"
DOCS = Path(__file__).parent.parent / "docs"
EXAMPLE = "<!-- remote control example: tests/test_daemon_control.py runs this block -->"


# --- a robot: an MQTT v5 client asking the daemon things --------------------------------
@dataclass
class Robot:
    client: aiomqtt.Client
    device: str
    messages: list[aiomqtt.Message] = field(default_factory=list)
    arrived: asyncio.Event = field(default_factory=asyncio.Event)

    async def read(self) -> None:
        async for message in self.client.messages:
            self.messages.append(message)
            self.arrived.set()

    async def wait_for(
        self,
        match: Callable[[aiomqtt.Message], bool],
        within: float,
        what: str,
        start: int = 0,
    ) -> aiomqtt.Message:
        """The first message from index ``start`` on that ``match`` takes."""
        deadline = time.monotonic() + within
        seen = start
        while True:
            for message in self.messages[seen:]:
                if match(message):
                    return message
            seen = len(self.messages)
            left = deadline - time.monotonic()
            if left <= 0:
                topics = [m.topic.value for m in self.messages[-5:]]
                msg = f"no {what} within {within} s; last topics: {topics}"
                raise AssertionError(msg)
            self.arrived.clear()
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(left):
                    await self.arrived.wait()

    async def ask(
        self,
        verb: str,
        payload: bytes | dict[str, Any] = b"",
        *,
        response_topic: str | None = None,
        correlation: bytes | None = None,
        reply_on: str | None = None,
        within: float = 10.0,
    ) -> tuple[aiomqtt.Message, dict[str, Any]]:
        """Send ``cmd/<verb>``; the reply (on ``reply_on``, else the response topic, else
        the default ``reply/<verb>``) and its JSON."""
        props = Properties(PacketTypes.PUBLISH)  # type: ignore[no-untyped-call]
        if response_topic is not None:
            props.ResponseTopic = response_topic
        if correlation is not None:
            props.CorrelationData = correlation
        expected = reply_on or response_topic or f"scotti/{self.device}/reply/{verb}"
        start = len(self.messages)
        body = json.dumps(payload).encode() if isinstance(payload, dict) else payload
        await self.client.publish(f"scotti/{self.device}/cmd/{verb}", body, qos=1, properties=props)

        def is_reply(m: aiomqtt.Message) -> bool:
            if m.topic.value != expected:
                return False
            return getattr(m.properties, "CorrelationData", None) == correlation

        message = await self.wait_for(is_reply, within, f"reply to {verb} on {expected}", start)
        data = json.loads(bytes(message.payload))
        Reply.model_validate(data)  # what docs/mqtt.md documents
        return message, data

    def payloads(self, name: str) -> list[dict[str, Any]]:
        suffix = f"scotti/{self.device}/{name}"
        return [json.loads(bytes(m.payload)) for m in self.messages if m.topic.value == suffix]

    async def poses_after(self, count: int, within: float = 20.0) -> int:
        """Wait for ``count`` more poses than now; the newest seq."""
        target = len(self.payloads("pose")) + count
        await self.wait_for(lambda _m: len(self.payloads("pose")) >= target, within, "poses")
        return int(self.payloads("pose")[-1]["seq"])


@contextlib.asynccontextmanager
async def robot(
    broker: Mosquitto, device: str, user: tuple[str, str] | None = None
) -> AsyncIterator[Robot]:
    async with aiomqtt.Client(
        broker.host,
        broker.port,
        username=user[0] if user else None,
        password=user[1] if user else None,
        protocol=aiomqtt.ProtocolVersion.V5,
    ) as client:
        await client.subscribe(f"scotti/{device}/#", qos=1)
        me = Robot(client, device)
        reader = asyncio.create_task(me.read())
        try:
            yield me
        finally:
            reader.cancel()
            await asyncio.gather(reader, return_exceptions=True)


def run_daemon(
    broker: Mosquitto,
    model: Path,
    tmp_path: Path,
    device: str,
    *extra: str,
    env: dict[str, str] | None = None,
) -> DaemonProcess:
    session = write_synthetic_session(tmp_path / f"{device}-in.scotti", frames=16 * SECONDS)
    args = ["--replay", str(session.path), "--model", str(model), "--broker", broker.url]
    args += ["--device-id", device, *extra]
    env = {"SCOTTI_MQTT_HEALTH_INTERVAL_S": "0.5", **(env or {})}
    return start_daemon(args, tmp_path / f"{device}.log", env=env)


def wait_ready(daemon: DaemonProcess, timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while READY not in daemon.log:
        assert daemon.proc.poll() is None, daemon.log
        assert time.monotonic() < deadline, daemon.log
        time.sleep(0.05)


def session_info(path: Path) -> dict[str, Any]:
    """``scotti session info --json``, as a user runs it."""
    exe = Path(sys.executable).with_name("scotti")
    out = subprocess.run(
        [str(exe), "session", "info", "--json", str(path)],
        capture_output=True,
        text=True,
        check=True,
        timeout=60,
    )
    result: dict[str, Any] = json.loads(out.stdout)
    return result


def mcap_messages(path: Path, topic: str) -> list[dict[str, Any]]:
    from mcap.reader import make_reader

    with path.open("rb") as f:
        return [json.loads(m.data) for _, _, m in make_reader(f).iter_messages(topics=[topic])]


# --- recording, events, replies ----------------------------------------------------------
@pytest.mark.mosquitto
@pytest.mark.slow
def test_start_mark_stop_makes_a_session_file_with_the_event(
    mosquitto: Mosquitto, tiny_model_path: Path, tmp_path: Path
) -> None:
    folder = tmp_path / "recordings"
    folder.mkdir()
    device = "ctl-rec"
    env = {"SCOTTI_MQTT_CONTROL_DIR": str(folder)}
    daemon = run_daemon(mosquitto, tiny_model_path, tmp_path, device, "--control", env=env)
    wait_ready(daemon)
    mcap_expected = mcap_missing() is None
    replies = f"scotti/{device}/reply/robot-7"

    async def session() -> dict[str, Any]:
        async with robot(mosquitto, device) as me:
            await me.poses_after(1)  # predicting: the recording has poses from its start
            started, start = await me.ask(
                "record/start", {"name": "trial1"}, response_topic=replies, correlation=b"\0r1"
            )
            assert started.properties.ContentType == "application/json"  # type: ignore[union-attr]
            _, again = await me.ask("record/start", response_topic=replies, correlation=b"r1b")
            seq_before = await me.poses_after(16)  # a second of frames
            _marked, mark = await me.ask(
                "event/mark",
                {"label": "squat set 2", "detail": "left knee"},
                response_topic=replies,
                correlation=b"r2",
            )
            echo = await me.wait_for(
                lambda m: m.topic.value == f"scotti/{device}/event", 5, "the event's echo"
            )
            _, reset = await me.ask("repetitions/reset", correlation=b"r3")
            await me.poses_after(8)
            _, stop = await me.ask("record/stop", response_topic=replies, correlation=b"r4")
            return {
                "start": start,
                "again": again,
                "mark": mark,
                "seq_before": seq_before,
                "echo": Event.model_validate_json(bytes(echo.payload)),
                "reset": reset,
                "stop": stop,
            }

    got = asyncio.run(session())
    assert daemon.stop() == 0, daemon.log
    session_path = folder / "trial1.scotti"
    mcap_path = folder / "trial1.mcap"
    start, mark, stop = got["start"], got["mark"], got["stop"]
    assert start["ok"] is True
    assert start["verb"] == "record/start"
    assert start["session"] == str(session_path)
    assert start.get("mcap") == (str(mcap_path) if mcap_expected else None)
    assert got["again"] == {**got["again"], "ok": False}
    assert got["again"]["reason"].startswith(f"already recording to {session_path}")
    written = [str(session_path), *([str(mcap_path)] if mcap_expected else [])]
    assert mark["ok"] is True
    assert mark["written_to"] == written
    assert mark["seq"] >= got["seq_before"]
    echo: Event = got["echo"]
    assert (echo.label, echo.detail, echo.written_to) == ("squat set 2", "left knee", written)
    assert got["reset"]["ok"] is True
    assert stop["ok"] is True
    assert stop["events"] == 1
    assert stop["seconds"] > 1.0
    assert stop["session"] == str(session_path)

    info = session_info(session_path)
    assert info["header"]["device"] == device
    assert info["events"]["count"] == 1
    (event,) = info["events"]["first"]
    assert (event["label"], event["detail"]) == ("squat set 2", "left knee")
    assert 0.5 < event["at_s"] < info["duration_s"]  # marked after a second of recording
    assert info["feet"]["left"]["frames"] > 16
    assert not info["truncated"]
    # Replay and evaluation read the packets only: the event is no record they know of.
    assert read_session(session_path).unknown_records == 0
    if mcap_expected:
        (logged,) = mcap_messages(mcap_path, "/events")
        assert logged["label"] == "squat set 2"
        assert logged["seq"] == mark["seq"]
        seqs = [p["seq"] for p in mcap_messages(mcap_path, "/pose")]
        assert seqs
        assert seqs == sorted(seqs)
        assert seqs[0] <= mark["seq"] <= seqs[-1]


@pytest.mark.mosquitto
@pytest.mark.slow
def test_bad_requests_are_answered_with_a_reason_and_counted(
    mosquitto: Mosquitto, tiny_model_path: Path, tmp_path: Path
) -> None:
    folder = tmp_path / "recordings"
    folder.mkdir()
    taken = [folder / "taken.scotti", folder / "taken2.mcap"]  # never overwritten
    for path in taken:
        path.write_bytes(b"an older recording")
    device = "ctl-bad"
    boot = tmp_path / "boot.scotti"
    env = {"SCOTTI_MQTT_CONTROL_DIR": str(folder)}
    daemon = run_daemon(
        mosquitto, tiny_model_path, tmp_path, device, "--control", "--record", str(boot), env=env
    )
    wait_ready(daemon)
    prefix = f"scotti/{device}"
    # (verb, payload, response topic or None, the reason's start)
    cases: list[tuple[str, bytes, str | None, str]] = [
        ("record/start", b"{not json", None, "malformed request: not JSON"),
        ("record/start", b'{"name": "../../etc/x"}', None, "malformed request: name: String"),
        ("record/start", b'{"name": "a", "size": 1}', None, "malformed request: size: Extra"),
        ("record/start", b"[1, 2]", None, "malformed request: a JSON object is wanted"),
        ("record/start", b" " * 5000, None, "malformed request: 5000 bytes; at most 4096"),
        ("event/mark", b"{}", None, "malformed request: label: Field required"),
        ("repetitions/reset", b'{"now": true}', None, "malformed request: now: Extra"),
        ("launch/rocket", b"{}", None, "unknown verb 'launch/rocket'; known: record/start"),
        ("record/start", b"{}", f"{prefix}/status", "response topic under scotti/ must be"),
        ("record/start", b"{}", f"{prefix}/cmd/record/stop", "response topic under scotti/"),
        ("record/start", b'{"name": "taken"}', None, f"{taken[0]} exists and is never"),
        (
            "record/start",
            b'{"name": "x{when}"}',
            None,
            f"{folder}/x{{when}}.scotti: unknown placeholder",
        ),
    ]
    if mcap_missing() is None:  # all or nothing: no session file left without its MCAP
        cases.append(("record/start", b'{"name": "taken2"}', None, f"{taken[1]} exists and"))

    async def session() -> tuple[list[dict[str, Any]], dict[str, Any], int, int]:
        async with robot(mosquitto, device) as me:
            await me.poses_after(1)
            _, stopped_boot = await me.ask("record/stop")  # the --record file
            answers = []
            for verb, payload, response_topic, _ in cases:
                # Refused response topics and unknown verbs: on the default reply topic.
                known = verb in ("record/start", "record/stop", "event/mark", "repetitions/reset")
                reply_on = f"{prefix}/reply/{verb if known else 'unknown'}"
                _, answer = await me.ask(
                    verb, payload, response_topic=response_topic, reply_on=reply_on
                )
                answers.append(answer)
            _, nothing = await me.ask("record/stop")
            _, unrecorded = await me.ask("event/mark", {"label": "no file"})
            answers += [nothing, unrecorded]
            before = await me.poses_after(1)
            after = await me.poses_after(16)  # still predicting and publishing
            counted = await me.wait_for(
                lambda m: m.topic.value == f"{prefix}/health" and _settled(m, len(cases) + 3),
                10,
                "health counting every request",
            )
            health = json.loads(bytes(counted.payload))
            return [stopped_boot, *answers], health["pipeline"]["control"], before, after

    answers, control, before, after = asyncio.run(session())
    assert daemon.stop() == 0, daemon.log
    stopped_boot, *bad, nothing, unrecorded = answers
    assert stopped_boot["ok"] is True
    assert stopped_boot["session"] == str(boot)
    assert "mcap" not in stopped_boot  # --record makes no MCAP file
    assert read_session(boot).packets  # closed whole: it reads back
    for (verb, _, _, reason), answer in zip(cases, bad, strict=True):
        assert answer["ok"] is False, (verb, answer)
        assert answer["reason"].startswith(reason), (verb, answer["reason"])
    assert nothing == {**nothing, "ok": False, "reason": "nothing is recording"}
    assert unrecorded["ok"] is True
    assert unrecorded["written_to"] == []
    assert unrecorded["note"] == "not recording: echoed on the event topic only"
    assert after > before
    assert sorted(folder.iterdir()) == sorted(taken)  # nothing refused wrote a file
    assert all(path.read_bytes() == b"an older recording" for path in taken)
    assert control["received"] == len(cases) + 3
    assert control["ok"] == 2
    assert control["refused"] == len(cases) + 1
    assert control["malformed"] == 7
    assert control["unknown_verb"] == 1
    assert control["dropped_queue_full"] == 0
    assert control["subscribed"] is True
    assert "Traceback" not in daemon.log


def test_reset_sets_the_repetition_count_to_zero(
    mosquitto: Mosquitto, tiny_model_path: Path, tmp_path: Path
) -> None:
    session = write_synthetic_session(tmp_path / "in.scotti", frames=8)
    pipeline = Pipeline(
        ReplaySource(session.path), ScottiRuntime(tiny_model_path), Counters()
    )  # never run: only its repetition counter is used
    counter = pipeline.repetitions
    squat = 0
    for progress in (0.1, 0.8, 0.1, 0.8, 0.1, 0.8):  # two repetitions and a third under way
        counted = counter.update(squat, progress)
    assert counted == 2
    settings = MqttSettings(broker=mosquitto.url, device_id="reps", control=True)

    async def go() -> dict[str, Any]:
        control = Control(settings, "reps", pipeline)
        stop = asyncio.Event()
        task = asyncio.create_task(control.run(stop))
        for _ in range(500):  # until the broker took the subscription
            if control.stats.subscribed:
                break
            await asyncio.sleep(0.02)
        async with robot(mosquitto, "reps") as me:
            _, reply = await me.ask("repetitions/reset", correlation=b"abc")
        stop.set()
        await task
        return reply

    assert asyncio.run(go())["ok"] is True
    assert counter.update(squat, 0.1) == 0  # without the reset: 3
    assert [counter.update(squat, p) for p in (0.8, 0.1)] == [0, 1]  # counts on from 0


@pytest.mark.mosquitto
@pytest.mark.slow
def test_the_documented_mosquitto_pub_example_does_what_it_says(
    mosquitto: Mosquitto, tiny_model_path: Path, tmp_path: Path
) -> None:
    if shutil.which("mosquitto_pub") is None:
        pytest.skip("mosquitto_pub not installed (mosquitto-clients)")
    block = (DOCS / "mqtt.md").read_text().split(EXAMPLE, 1)[1]
    block = block.split("```sh\n", 1)[1].split("```", 1)[0]
    # mosquitto_pub reads default options from $XDG_CONFIG_HOME/mosquitto_pub: the test
    # broker's port, without changing the commands the docs show.
    config = tmp_path / "config"
    config.mkdir()
    (config / "mosquitto_pub").write_text(f"-h {mosquitto.host}\n-p {mosquitto.port}\n")
    folder = tmp_path / "recordings"
    folder.mkdir()
    env = {"SCOTTI_MQTT_CONTROL_DIR": str(folder)}
    daemon = run_daemon(mosquitto, tiny_model_path, tmp_path, "lab1", "--control", env=env)
    wait_ready(daemon)

    async def session() -> list[tuple[str, bytes | None, dict[str, Any]]]:
        async with robot(mosquitto, "lab1") as me:
            await me.poses_after(1)
            shell = {**os.environ, "XDG_CONFIG_HOME": str(config)}
            ran = await asyncio.to_thread(
                subprocess.run, ["bash", "-e", "-c", block], env=shell, timeout=60, check=False
            )
            assert ran.returncode == 0

            def replies() -> list[aiomqtt.Message]:
                return [m for m in me.messages if "/reply/" in m.topic.value]

            await me.wait_for(lambda _m: len(replies()) >= 4, 10, "four replies")
            return [
                (
                    m.topic.value,
                    getattr(m.properties, "CorrelationData", None),
                    json.loads(bytes(m.payload)),
                )
                for m in replies()
            ]

    replies = asyncio.run(session())
    assert daemon.stop() == 0, daemon.log
    robot_topic = "scotti/lab1/reply/robot1"
    assert [(t, c, r["verb"], r["ok"]) for t, c, r in replies] == [
        (robot_topic, b"req-1", "record/start", True),
        (robot_topic, b"req-2", "event/mark", True),
        (robot_topic, b"req-3", "record/stop", True),
        ("scotti/lab1/reply/repetitions/reset", None, "repetitions/reset", True),
    ]
    (recorded,) = folder.glob("squats-*.scotti")  # {time} filled in
    info = session_info(recorded)
    assert [(e["label"], e["detail"]) for e in info["events"]["first"]] == [
        ("set 2", "left knee sore")
    ]


# --- who may ask -----------------------------------------------------------------------
ACL = """\
# the daemon: takes requests, publishes everything else under its prefix
user scotti
topic read scotti/+/cmd/#
topic write scotti/+/+
topic write scotti/+/reply/#

# a robot chosen to control it
user robot
topic write scotti/+/cmd/#
topic read scotti/#

# everyone else who may log in: read only
user viewer
topic read scotti/#
"""
USERS = {"scotti": "daemon-pw", "robot": "robot-pw", "viewer": "viewer-pw"}


@pytest.fixture
def acl_broker() -> Iterator[Mosquitto]:
    """mosquitto with a password file of three users and the ACL above (docs/mqtt.md)."""
    folder = Path(tempfile.mkdtemp(prefix="scotti-acl-"))
    folder.chmod(0o755)  # mosquitto started as root reads its files as user "mosquitto"
    users = folder / "passwd"
    users.write_text("".join(f"{u}:{p}\n" for u, p in USERS.items()))
    subprocess.run(["mosquitto_passwd", "-U", str(users)], check=True)
    acl = folder / "acl"
    acl.write_text(ACL)
    for path in (users, acl):
        path.chmod(0o644)
    conf = ["allow_anonymous false", f"password_file {users}", f"acl_file {acl}"]
    broker = Mosquitto(extra_conf=conf)  # later lines win: no anonymous clients
    try:
        broker.start()
        yield broker
    finally:
        broker.close()
        for path in (users, acl):
            path.unlink()
        folder.rmdir()


def _publish_as(broker: Mosquitto, user: str, topic: str) -> int:
    """Publish at QoS 1 as ``user`` (paho, to see the broker's answer); the PUBACK's
    reason code (135: not authorised)."""
    acked: list[int] = []
    client = paho.Client(CallbackAPIVersion.VERSION2, protocol=paho.MQTTv5)
    client.username_pw_set(user, USERS[user])
    client.on_publish = lambda _c, _u, _mid, rc, _p: acked.append(rc.value)
    client.connect(broker.host, broker.port)
    client.loop_start()
    try:
        client.publish(topic, b"{}", qos=1).wait_for_publish(10)
        deadline = time.monotonic() + 10
        while not acked and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        client.loop_stop()
        client.disconnect()
    return acked[0]


@pytest.mark.mosquitto
@pytest.mark.slow
def test_only_clients_the_acl_allows_can_make_the_daemon_do_anything(
    acl_broker: Mosquitto, tiny_model_path: Path, tmp_path: Path
) -> None:
    folder = tmp_path / "recordings"
    folder.mkdir()
    device = "ctl-acl"
    env = {
        "SCOTTI_MQTT_CONTROL_DIR": str(folder),
        "SCOTTI_MQTT_USERNAME": "scotti",
        "SCOTTI_MQTT_PASSWORD": USERS["scotti"],
    }
    daemon = run_daemon(acl_broker, tiny_model_path, tmp_path, device, "--control", env=env)
    wait_ready(daemon)
    prefix = f"scotti/{device}"

    async def session() -> tuple[dict[str, Any], list[int], dict[str, Any], dict[str, Any]]:
        async with robot(acl_broker, device, ("robot", USERS["robot"])) as me:
            await me.poses_after(1)
            _, started = await me.ask("record/start", {"name": "allowed"}, correlation=b"1")
            # The viewer may log in and read, not ask: the broker refuses its publishes.
            refused = [
                await asyncio.to_thread(_publish_as, acl_broker, "viewer", f"{prefix}/cmd/{verb}")
                for verb in ("record/stop", "repetitions/reset", "event/mark")
            ]
            # An anonymous client does not get in at all.
            with pytest.raises(aiomqtt.MqttError):
                async with aiomqtt.Client(acl_broker.host, acl_broker.port, timeout=5):
                    pass
            await me.poses_after(8)
            health = await me.wait_for(
                lambda m: m.topic.value == f"{prefix}/health",
                10,
                "a health after the viewer's tries",
                start=len(me.messages),
            )
            _, stopped = await me.ask("record/stop", correlation=b"2")
            control = json.loads(bytes(health.payload))["pipeline"]["control"]
            return started, refused, control, stopped

    started, refused, control, stopped = asyncio.run(session())
    assert daemon.stop() == 0, daemon.log
    assert started["ok"] is True
    assert refused == [135, 135, 135]  # Not authorized
    # The daemon never saw the viewer's requests: one request so far, the robot's start;
    # the recording ran on until the robot stopped it.
    assert control["received"] == 1
    assert control["subscribed"] is True
    assert stopped["ok"] is True
    assert stopped["events"] == 0
    assert stopped["session"] == str(folder / "allowed.scotti")


# --- off by default ------------------------------------------------------------------------
@pytest.mark.mosquitto
@pytest.mark.slow
def test_control_is_off_by_default(
    mosquitto: Mosquitto, tiny_model_path: Path, tmp_path: Path
) -> None:
    folder = tmp_path / "recordings"
    folder.mkdir()
    device = "ctl-off"
    env = {"SCOTTI_MQTT_CONTROL_DIR": str(folder)}  # where a recording would go: none does
    daemon = run_daemon(mosquitto, tiny_model_path, tmp_path, device, env=env)

    async def session() -> tuple[list[str], dict[str, Any]]:
        async with robot(mosquitto, device) as me:
            await me.poses_after(1)
            for verb in ("record/start", "event/mark", "repetitions/reset"):
                payload = {"label": "x"} if verb == "event/mark" else {}
                with pytest.raises(AssertionError, match="no reply"):
                    await me.ask(
                        verb, payload, response_topic=f"scotti/{device}/reply/r", within=1.5
                    )
            await me.poses_after(16)
            topics = sorted({m.topic.value.removeprefix(f"scotti/{device}/") for m in me.messages})
            return topics, me.payloads("health")[-1]

    topics, health = asyncio.run(session())
    assert daemon.stop() == 0, daemon.log
    assert list(folder.iterdir()) == []
    assert "control" not in health["pipeline"]
    assert "reply/r" not in topics
    assert "event" not in topics
    assert "remote control" not in daemon.log


# --- a flood ----------------------------------------------------------------------------------
@pytest.mark.mosquitto
@pytest.mark.slow
def test_a_flood_of_requests_is_dropped_and_counted_while_poses_keep_flowing(
    tiny_model_path: Path, tmp_path: Path
) -> None:
    seconds = 3.0
    result = control_flood.run(seconds, 1000.0, tiny_model_path, tmp_path / "daemon.log")
    log = (tmp_path / "daemon.log").read_text()
    assert result["daemon_exit"] == 0, log
    per_window = seconds * 16
    for window in control_flood.WINDOWS:  # quiet, flood, after
        assert result[window]["poses"] >= 0.8 * per_window, (window, result)
    counts = result["counts"]
    assert counts["dropped_queue_full"] > 0
    assert counts["flood_pauses"] >= 1  # it stopped listening: the broker kept the flood
    # Handled one at a time, at most control_rate (20) a second, plus the queue (8).
    assert 0 < counts["received"] <= 20 * (seconds + 1) + 8
    assert counts["received"] == counts["ok"]
    assert "Traceback" not in log


def test_after_a_flood_it_stops_listening_for_a_while_then_answers_again(
    mosquitto: Mosquitto, tiny_model_path: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import scotti.daemon.mqtt.control as control_module

    monkeypatch.setattr(control_module, "FLOOD_PAUSE_S", 1.0)  # 5 s in the daemon
    session = write_synthetic_session(tmp_path / "in.scotti", frames=8)
    pipeline = Pipeline(ReplaySource(session.path), ScottiRuntime(tiny_model_path), Counters())
    settings = MqttSettings(broker=mosquitto.url, device_id="flooded", control=True)

    async def go() -> tuple[list[bool], dict[str, Any], dict[str, Any]]:
        control = Control(settings, "flooded", pipeline)
        stop = asyncio.Event()
        task = asyncio.create_task(control.run(stop))
        for _ in range(500):  # until the broker took the subscription
            if control.stats.subscribed:
                break
            await asyncio.sleep(0.02)
        topic = "scotti/flooded/cmd/event/mark"
        async with robot(mosquitto, "flooded") as me:
            for i in range(400):  # as fast as one client can
                await me.client.publish(topic, json.dumps({"label": f"f{i}"}).encode())
            subscribed = []
            for _ in range(100):
                subscribed.append(control.stats.subscribed)
                if not control.stats.subscribed:
                    break
                await asyncio.sleep(0.02)
            # Meanwhile nobody listens: the broker drops a request (no session is kept).
            with pytest.raises(AssertionError, match="no reply"):
                await me.ask("repetitions/reset", correlation=b"during", within=0.3)
            for _ in range(250):
                if control.stats.subscribed:
                    break
                await asyncio.sleep(0.02)
            _, reply = await me.ask("repetitions/reset", correlation=b"after")
        stop.set()
        await task
        return subscribed, reply, control.stats.as_dict()

    subscribed, reply, stats = asyncio.run(go())
    assert subscribed[-1] is False  # it unsubscribed
    assert stats["flood_pauses"] >= 1  # more when the broker's backlog outlasts the pause
    assert stats["dropped_queue_full"] > 40  # two seconds' worth at 20 requests/s
    assert reply["ok"] is True  # and answers again once the pause is over
    assert stats["subscribed"] is True


# --- settings ----------------------------------------------------------------------------------
def test_control_settings_from_flag_environment_and_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    for key in [k for k in os.environ if k.startswith("SCOTTI_")]:
        monkeypatch.delenv(key)
    source = {"source": {"simulate": "demo"}}
    assert load_settings(source).mqtt.control is False  # off by default
    cli = cli_overrides(build_parser().parse_args(["--simulate", "demo", "--control"]))
    assert load_settings(cli).mqtt.control is True
    monkeypatch.setenv("SCOTTI_MQTT_CONTROL", "true")
    monkeypatch.setenv("SCOTTI_MQTT_CONTROL_DIR", str(tmp_path))
    from_env = load_settings(source).mqtt
    assert (from_env.control, from_env.control_dir) == (True, tmp_path)
    monkeypatch.delenv("SCOTTI_MQTT_CONTROL")
    config = tmp_path / "d.toml"
    config.write_text("[mqtt]\ncontrol = true\ncontrol_queue = 4\ncontrol_rate = 5\n")
    from_file = load_settings(source, config).mqtt
    assert (from_file.control, from_file.control_queue, from_file.control_rate) == (True, 4, 5.0)
    monkeypatch.setenv("SCOTTI_MQTT_CONTROL_DIR", str(tmp_path / "missing"))
    with pytest.raises(ConfigError, match=r"control_dir: not a directory: .*missing"):
        load_settings({**source, "mqtt": {"control": True}})
    assert load_settings(source).mqtt.control is False  # off: the folder is not looked at


def test_a_control_dir_that_is_not_a_directory_is_one_line_and_exit_78(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    for key in [k for k in os.environ if k.startswith("SCOTTI_")]:
        monkeypatch.delenv(key)
    monkeypatch.setenv("SCOTTI_MQTT_CONTROL_DIR", str(tmp_path / "nope"))
    assert main(["--simulate", "demo", "--control"]) == 78
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "control_dir: not a directory" in err


# --- the event record ------------------------------------------------------------------------
def test_event_records_are_read_only_when_asked_for(tmp_path: Path) -> None:
    path = tmp_path / "events.scotti"
    marked = EventRecord(2_000, "trial 3", "", 1_700_000_000_000_000_000)
    with SessionWriter(path, SessionHeader(source="recorded")) as writer:
        writer.write_packet(1_000, b"\x00ab")
        writer.write(marked)
        writer.write_packet(3_000, b"\x00cd")
    session = read_session(path)  # replay, eval, import: packets and labels only
    assert [p.t_ns for p in session.packets] == [1_000, 3_000]
    assert session.unknown_records == 0
    assert session.bad_records == 0
    records = list(iter_records(path, events=True))[1:]
    assert records == [PacketRecord(1_000, b"\x00ab"), marked, PacketRecord(3_000, b"\x00cd")]
    assert EventRecord.from_record(marked.to_record()) == marked


def _settled(message: aiomqtt.Message, requests: int) -> bool:
    """A health report that counts every request as taken and answered: one sent while
    the last request was still being answered (its echo on the event topic on the
    way) counts it received but not yet ok."""
    control = json.loads(bytes(message.payload))["pipeline"]["control"]
    return bool(control["received"] == control["ok"] + control["refused"] == requests)
