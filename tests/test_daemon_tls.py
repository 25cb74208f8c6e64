"""TLS and a password file against a real mosquitto: right CA connects, wrong CA or
wrong password is one WARNING with the reason, and the daemon keeps trying (no crash loop)."""

from __future__ import annotations

import shutil
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from scotti.daemon.tools.local_broker import Mosquitto

from tests.support.broker import DaemonProcess, collect, payloads, start_daemon
from tests.support.certs import Certs, make_certs

USER, PASSWORD = "scotti", "right-password"
pytestmark = [pytest.mark.mosquitto, pytest.mark.slow]


@pytest.fixture(scope="module")
def certs() -> Iterator[Certs]:
    if shutil.which("openssl") is None:
        pytest.skip("openssl not found")
    made = make_certs()
    yield made
    shutil.rmtree(made.folder, ignore_errors=True)


@pytest.fixture
def tls_broker(certs: Certs) -> Iterator[Mosquitto]:
    broker = Mosquitto(
        password=(USER, PASSWORD), tls=(certs.ca, certs.server_cert, certs.server_key)
    )
    try:
        broker.start()
        yield broker
    finally:
        broker.close()


def run_tls_daemon(
    broker: Mosquitto, ca: Path, password: str, device: str, tiny: Path, log: Path
) -> DaemonProcess:
    args = ["--port", "/dev/scotti-no-such-port", "--model", str(tiny)]
    args += ["--broker", broker.tls_url, "--tls-ca-file", str(ca), "--device-id", device]
    env = {
        "SCOTTI_MQTT_USERNAME": USER,
        "SCOTTI_MQTT_PASSWORD": password,
        "SCOTTI_MQTT_RECONNECT_MAX_S": "0.3",
    }
    return start_daemon(args, log, env=env)


def broker_lines(daemon: DaemonProcess) -> list[str]:
    return [line for line in daemon.log.splitlines() if "scotti.daemon.mqtt.publisher" in line]


def wait_for_line(daemon: DaemonProcess, text: str, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if text in daemon.log:
            return
        assert daemon.proc.poll() is None, daemon.log
        time.sleep(0.1)
    raise AssertionError(f"no {text!r} in the log within {timeout} s:\n{daemon.log}")


def test_right_ca_and_password_connect(
    tls_broker: Mosquitto, certs: Certs, tiny_model_path: Path, tmp_path: Path
) -> None:
    with collect(tls_broker, "scotti/tlsok/#") as got:  # the plain listener, same password
        daemon = run_tls_daemon(
            tls_broker, certs.ca, PASSWORD, "tlsok", tiny_model_path, tmp_path / "ok.log"
        )
        try:
            got.wait_for(lambda m: payloads(m, "info") and payloads(m, "status"), 60, "info")
        finally:
            assert daemon.stop() == 0, daemon.log
    assert payloads(got.snapshot(), "info")[0]["device_id"] == "tlsok"
    assert not [line for line in broker_lines(daemon) if line.startswith("WARNING")]
    assert "ERROR" not in daemon.log
    assert "Traceback" not in daemon.log


@pytest.mark.parametrize(
    ("wrong", "reason"),
    [("ca", "certificate verify failed"), ("password", "Not authorized")],
)
def test_refused_is_one_warning_and_no_crash_loop(
    wrong: str,
    reason: str,
    tls_broker: Mosquitto,
    certs: Certs,
    tiny_model_path: Path,
    tmp_path: Path,
) -> None:
    ca = certs.other_ca if wrong == "ca" else certs.ca
    password = "wrong-password" if wrong == "password" else PASSWORD
    device = f"refused-{wrong}"
    with collect(tls_broker, f"scotti/{device}/#") as got:
        daemon = run_tls_daemon(
            tls_broker, ca, password, device, tiny_model_path, tmp_path / "x.log"
        )
        try:
            wait_for_line(daemon, reason, 60)
            time.sleep(2.0)  # several retries (backoff capped at 0.3 s)
            assert daemon.proc.poll() is None, daemon.log  # still running: no crash loop
        finally:
            assert daemon.stop() == 0, daemon.log
    warnings = [line for line in broker_lines(daemon) if line.startswith("WARNING")]
    assert len(warnings) == 1, daemon.log
    assert reason in warnings[0]
    assert "ERROR" not in daemon.log
    assert "Traceback" not in daemon.log
    assert not got.snapshot()  # nothing got through


def test_unreadable_tls_file_is_one_line_exit_78(certs: Certs, tmp_path: Path) -> None:
    from tests.test_daemon_faults import assert_one_line, run_daemon

    junk = tmp_path / "junk.pem"
    junk.write_text("not a certificate\n")
    out = run_daemon(
        "--port", "/dev/x", "--broker", "mqtts://localhost:8883", "--tls-ca-file", str(junk)
    )
    assert_one_line(out, "scotti-daemon: config error: mqtt TLS files")
    missing = run_daemon(
        "--port", "/dev/x", "--broker", "mqtt://localhost", "--tls-ca-file", str(certs.ca)
    )
    assert_one_line(missing, "scotti-daemon: config error: mqtt: tls_ca_file given but")
