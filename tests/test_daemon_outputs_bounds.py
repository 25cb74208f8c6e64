"""The network outputs against hostile neighbours, over real sockets: a cap on
connections (refused beyond it, counted, logged once per burst, the readers already in
go on), Host and Origin allow lists, the token; the same for the Foxglove gate; and a
daemon under a low descriptor limit flooded with connections while its MQTT path goes on
(a real mosquitto), with no ERROR line in its log."""

from __future__ import annotations

import asyncio
import contextlib
import http.client
import json
import logging
import os
import socket
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from scotti.daemon.frames.pipeline import Prediction
from scotti.daemon.outputs import guard
from scotti.daemon.tools.local_broker import Mosquitto

from tests.support.broker import DaemonProcess, collect
from tests.support.outputs import predictions
from tests.support.sessions import write_synthetic_session


@pytest.fixture(scope="module")
def preds(tmp_path_factory: pytest.TempPathFactory, tiny_model_path: Path) -> list[Prediction]:
    session = write_synthetic_session(tmp_path_factory.mktemp("bounds") / "s.scotti", frames=44)
    return predictions(session.path, tiny_model_path)


class Served:
    """A ``WebOutput`` on its own event loop thread, fed as the daemon feeds it."""

    def __init__(self, rules: guard.Rules) -> None:
        from scotti.daemon.outputs.web import WebOutput

        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()
        start = WebOutput.start("127.0.0.1", 0, ("scotti",), rules)
        self.output = asyncio.run_coroutine_threadsafe(start, self.loop).result(10)
        self.port = self.output.port

    def send(self, p: Prediction) -> None:
        self.loop.call_soon_threadsafe(self.output.prediction, "scotti", p, 1.0)

    def until(self, check: Any, what: str) -> None:
        assert self.output.front.wait_for(check, 10), (what, self.output.counters)

    def close(self) -> None:
        asyncio.run_coroutine_threadsafe(self.output.close(), self.loop).result(10)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(5)
        self.loop.close()


@contextlib.contextmanager
def served(**rules: Any) -> Iterator[Served]:
    s = Served(guard.Rules(**rules))
    try:
        yield s
    finally:
        s.close()


def get(port: int, path: str, headers: dict[str, str] | None = None) -> tuple[int, str, bytes]:
    """Status, Set-Cookie and body of one GET (``Host`` is http.client's unless given)."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    try:
        conn.request("GET", path, headers=headers or {})
        response = conn.getresponse()
        body = b"" if path.endswith("events") else response.read()
        return response.status, response.getheader("Set-Cookie") or "", body
    finally:
        conn.close()


class Reader:
    """A raw feed reader: connects, sends its request, reads events."""

    def __init__(self, port: int, path: str = "/events", extra: str = "") -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=10)
        self.sock.sendall(f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n{extra}\r\n".encode())
        self.buffer = b""

    def head(self) -> bytes:
        """The reply's first line; b"" when the server closed (or reset) without one."""
        while b"\r\n" not in self.buffer:
            try:
                data = self.sock.recv(4096)
            except ConnectionResetError:
                return b""
            if not data:
                return self.buffer
            self.buffer += data
        return self.buffer.split(b"\r\n", 1)[0]

    def event(self) -> dict[str, Any]:
        while b"data: " not in self.buffer or b"\n\n" not in self.buffer.split(b"data: ", 1)[1]:
            data = self.sock.recv(1 << 16)
            assert data, "the feed ended"
            self.buffer += data
        _, _, rest = self.buffer.partition(b"data: ")
        line, _, self.buffer = rest.partition(b"\n\n")
        return json.loads(line)  # type: ignore[no-any-return]

    def close(self) -> None:
        self.sock.close()


def test_connections_over_the_cap_are_refused_while_readers_go_on(
    preds: list[Prediction], caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO)
    with served(max_connections=4) as web:
        readers = [Reader(web.port) for _ in range(4)]
        for r in readers:
            assert r.event()["type"] == "hello"
        web.until(lambda f: 0 in f.watched and f.counters["connections"] == 4, "4 in")
        flood = [Reader(web.port) for _ in range(40)]
        heads = [r.head() for r in flood]
        for r in flood:
            r.close()
        assert not [h for h in heads if h.startswith(b"HTTP/1.1 200")]
        assert b"HTTP/1.1 503 Service Unavailable" in heads  # said, where not reset first
        web.until(lambda f: f.counters["refused"]["over_cap"] == 40, "40 refused")
        web.send(preds[0])  # the readers already in still get every frame
        assert [r.event()["seq"] for r in readers] == [preds[0].seq] * 4
        readers.pop().close()  # one leaves: its place is free again
        web.until(lambda f: f.counters["connections"] == 3, "one left")
        late = Reader(web.port)
        assert late.head() == b"HTTP/1.1 200 OK"
        late.close()
        for r in readers:
            r.close()
    assert web.output.counters["refused"]["over_cap"] == 40
    assert not [r for r in caplog.records if r.levelno >= logging.ERROR]
    burst = [r for r in caplog.records if "refused connections" in r.getMessage()]
    assert 1 <= len(burst) <= 2, [r.getMessage() for r in burst]  # not one per connection
    assert "40 refused in all" in burst[-1].getMessage()


@pytest.mark.parametrize(
    ("headers", "status", "reason"),
    [
        ({"Host": "evil.example:80"}, 403, guard.HOST),  # a rebound name
        ({"Host": "localhost"}, 200, None),
        ({"Host": "[::1]:8080"}, 200, None),
        ({"Host": "192.168.1.20:8080"}, 200, None),  # an address typed by the user
        ({"Host": "robot.lan:8080"}, 200, None),  # allowed below
        ({"Host": "robot.lan.evil.example"}, 403, guard.HOST),
        ({"Origin": "http://evil.example"}, 403, guard.ORIGIN),
        ({"Origin": "http://localhost:3000"}, 403, guard.ORIGIN),  # another local page
        ({"Origin": "https://app.foxglove.dev"}, 200, None),  # allowed below
        ({"Origin": "SAME"}, 200, None),  # the view's own page
    ],
)
def test_host_and_origin_allow_lists(headers: dict[str, str], status: int, reason: str) -> None:
    with served(allowed_hosts=("robot.lan",), allowed_origins=("https://app.foxglove.dev",)) as web:
        if headers.get("Origin") == "SAME":
            headers = {"Origin": f"http://127.0.0.1:{web.port}"}
        got, _, _ = get(web.port, "/devices", headers)
        assert got == status
        if reason is not None:
            web.until(lambda f: f.counters["refused"][reason] == 1, reason)
    assert sum(web.output.counters["refused"].values()) == (reason is not None)


def test_the_token_when_set_is_required_and_the_page_passes_it_to_its_feed() -> None:
    with served(token="s3cret") as web:
        assert get(web.port, "/")[0] == 401
        assert get(web.port, "/?token=wrong")[0] == 401
        assert get(web.port, "/events", {"Authorization": "Bearer nope"})[0] == 401
        status, cookie, page = get(web.port, "/?token=s3cret")
        assert status == 200
        assert b"EventSource" in page
        assert cookie.startswith(f"{guard.TOKEN_COOKIE}=s3cret;")
        assert "HttpOnly" in cookie
        by_cookie = Reader(web.port, extra=f"Cookie: {cookie.split(';')[0]}\r\n")
        assert by_cookie.event()["type"] == "hello"  # the page's EventSource sends it back
        by_header = Reader(web.port, extra="Authorization: Bearer s3cret\r\n")
        assert by_header.event()["type"] == "hello"
        for r in (by_cookie, by_header):
            r.close()
        web.until(lambda f: f.counters["refused"][guard.TOKEN] == 3, "3 without it")


def test_the_foxglove_gate_caps_checks_and_passes_the_protocol_through(
    preds: list[Prediction],
) -> None:
    pytest.importorskip("foxglove")
    websockets = pytest.importorskip("websockets")
    from scotti.daemon.outputs.foxglove_out import FoxgloveOutput
    from websockets.exceptions import InvalidStatus

    rules = guard.Rules(max_connections=2, token="tok")
    output = FoxgloveOutput(mcap=None, port=0, rules=rules)
    url = f"ws://127.0.0.1:{output.port}/"
    sub = ["foxglove.sdk.v1"]

    async def refused(uri: str, **kw: Any) -> int:
        try:
            async with websockets.connect(uri, subprotocols=sub, open_timeout=10, **kw):
                return 101
        except InvalidStatus as exc:
            return int(exc.response.status_code)

    async def hears(ws: Any, topic: str) -> bool:
        """Until ``topic`` is advertised to ``ws`` (one advertise per new channel)."""
        while True:
            msg = await asyncio.wait_for(ws.recv(), 10)
            data = json.loads(msg) if isinstance(msg, str) else {}
            if data.get("op") == "advertise" and topic in {c["topic"] for c in data["channels"]}:
                return True

    async def session() -> None:
        assert await refused(url) == 401
        assert await refused(url + "?token=wrong") == 401
        assert await refused(url + "?token=tok", origin="http://evil.example") == 403
        assert await refused(url + "?token=tok", additional_headers={"Host": "evil.example"}) == 403
        bearer = {"Authorization": "Bearer tok"}
        async with (
            websockets.connect(url + "?token=tok", subprotocols=sub) as one,
            websockets.connect(url, subprotocols=sub, additional_headers=bearer) as two,
        ):
            assert one.subprotocol == two.subprotocol == "foxglove.sdk.v1"
            assert await hears(one, "/skeleton")
            assert await hears(two, "/skeleton")
            assert output.gate is not None
            gate = output.gate
            assert await asyncio.to_thread(
                gate.wait_for, lambda f: f.counters["connections"] == 2, 10
            )
            with pytest.raises((InvalidStatus, OSError, EOFError)):
                async with websockets.connect(url + "?token=tok", subprotocols=sub):
                    pass  # the third is over the cap
            output.prediction("scotti", preds[0], 1.0)  # new JSON channels: both still hear
            assert await hears(one, "/action")
            assert await hears(two, "/action")

    try:
        # The SDK's own server checks nothing: it is not where a page scanning 127.0.0.1
        # would find it (Linux binds any 127/8 address; elsewhere it stays 127.0.0.1).
        assert output.sdk_address is not None
        sdk_host, sdk_port = output.sdk_address
        assert sdk_host.startswith("127.")
        if sys.platform == "linux":
            assert sdk_host != "127.0.0.1"
            with pytest.raises(ConnectionRefusedError):
                socket.create_connection(("127.0.0.1", sdk_port), timeout=5).close()
        asyncio.run(session())
        assert output.gate is not None
        gate = output.gate
        refused_of = {guard.TOKEN: 2, guard.ORIGIN: 1, guard.HOST: 1, guard.OVER_CAP: 1}
        assert gate.wait_for(
            lambda f: all(f.counters["refused"][k] == n for k, n in refused_of.items()), 10
        ), gate.counters
    finally:
        asyncio.run(output.close())


def test_the_refusal_log_is_one_line_per_burst(caplog: pytest.LogCaptureFixture) -> None:
    now = [100.0]
    scheduled: list[Any] = []
    log = guard.RefusalLog(
        "web", guard.Rules(), lambda delay, f: scheduled.append(f), clock=lambda: now[0]
    )
    with caplog.at_level(logging.WARNING):
        for _ in range(1000):
            log.refused(guard.OVER_CAP)
        assert len(caplog.records) == 1  # the first, at once
        assert len(scheduled) == 1  # the rest: one line, later
        now[0] += guard.BURST_LOG_S
        scheduled[0]()
    assert len(caplog.records) == 2
    assert "999 over the cap" in caplog.records[1].getMessage()
    assert log.counts[guard.OVER_CAP] == 1000


def test_request_heads_that_are_not_http_are_refused() -> None:
    rules = guard.Rules()
    assert guard.refusal(guard.parse_head(b"\x16\x03\x01garbage\r\n"), rules) == guard.BAD_REQUEST
    assert guard.refusal(guard.parse_head(b"GET / HTTP/1.1\r\n"), rules) == guard.BAD_REQUEST
    ok = guard.parse_head(b"GET /x?token=a%20b HTTP/1.1\r\nHost: [::1]:80\r\n")
    assert ok is not None
    assert ok.query == {"token": "a b"}
    assert guard.refusal(ok, rules) is None
    assert guard.host_name("Example.COM:80") == "example.com"


def _fds(pid: int) -> int:
    return len(os.listdir(f"/proc/{pid}/fd"))


@pytest.mark.mosquitto
def test_a_flood_of_connections_under_a_low_descriptor_limit_leaves_mqtt_alone(
    mosquitto: Mosquitto, tiny_model_path: Path, tmp_path: Path
) -> None:
    """The daemon under ``ulimit -n 128`` (the front's too: it cannot raise it) asked for
    1,000 web connections: the front caps itself at what fits and says so once; 300
    connections later the daemon's own descriptors are as few as before (the
    connections are the front's), its poses still reach MQTT, a reader that was in
    first still gets frames, and the log has no ERROR line."""
    port = _free_port()
    device = "flooded"
    log_path = tmp_path / "d.log"
    args = ["--simulate", "all-actions", "--model", str(tiny_model_path),
            "--broker", mosquitto.url, "--device-id", device,
            "--web", str(port), "--max-connections", "1000"]  # fmt: skip
    exe = Path(sys.executable).with_name("scotti-daemon")
    clean = {k: v for k, v in os.environ.items() if not k.startswith("SCOTTI_")}
    clean.pop("NOTIFY_SOCKET", None)
    import shlex
    import subprocess

    line = f"ulimit -n 128 && exec {shlex.quote(str(exe))} {shlex.join(args)}"
    with log_path.open("wb") as out:
        proc = subprocess.Popen(["sh", "-c", line], stdout=out, stderr=subprocess.STDOUT, env=clean)
    daemon = DaemonProcess(proc, log_path)
    flood: list[socket.socket] = []
    try:
        with collect(mosquitto, f"scotti/{device}/pose") as got:
            got.wait_for(lambda m: len(m) >= 3, 60, "poses before the flood")
            first = Reader(port)
            assert first.event()["type"] == "hello"
            before = _fds(proc.pid)
            for _ in range(300):
                with contextlib.suppress(OSError):
                    flood.append(socket.create_connection(("127.0.0.1", port), timeout=10))
            poses = len(got.snapshot())
            got.wait_for(lambda m: len(m) >= poses + 16, 30, "poses after the flood")
            assert first.event()["type"] in ("frame", "status")  # the first reader goes on
            assert first.event()["type"] in ("frame", "status")
            assert _fds(proc.pid) <= before + 2  # the flood's descriptors are not the daemon's
            first.close()
    finally:
        for s in flood:
            s.close()
        daemon.stop()
    text = daemon.log
    errors = [ln for ln in text.splitlines() if ln.startswith("ERROR ") or " ERROR " in ln]
    assert not errors, errors[:5]
    assert "Traceback" not in text, text[-3000:]
    assert "at most 96 connections (not 1000)" in text, text[-3000:]
    refusals = [ln for ln in text.splitlines() if "refused connections" in ln]
    assert 1 <= len(refusals) <= 3, refusals  # a line per burst, not per connection


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_the_servers_process_yields_the_cpu_to_everything_else(preds: list[Prediction]) -> None:
    """The front process runs in the idle scheduling class (nice 19 where there is none),
    so a thousand readers wait for the CPU, not the daemon's MQTT path; and it still
    serves."""
    from scotti.daemon.outputs.yield_cpu import scheduling_of

    with served() as s:
        pid = s.output.front.proc.pid
        reader = Reader(s.port)
        assert reader.head().endswith(b"200 OK")
        assert reader.event()["type"] == "hello"
        s.until(lambda f: 0 in f.watched, "the reader in")
        s.send(preds[0])
        assert reader.event()["seq"] == preds[0].seq
        expected = "SCHED_IDLE" if hasattr(os, "SCHED_IDLE") else "nice 19"
        assert scheduling_of(pid) == expected
        assert scheduling_of(os.getpid()) != expected  # the daemon's own process is left as is
        reader.close()
