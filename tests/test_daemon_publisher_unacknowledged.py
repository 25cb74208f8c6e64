"""A broker that takes the connection but never acknowledges a publish.

The publisher runs as a process of its own (``tests/support/publishing.py``)
against ``SilentBroker`` (CONNACK, SUBACK and PINGRESP, never a PUBACK); its
CPU is read from outside with psutil while predictions keep coming at 16 Hz.
Before this publisher it spun: 85-94 % of a core in issue 41's measurement,
24.7 % here on a loaded 2-core machine (the same command, aiomqtt 2.5).
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest
from scotti.daemon.tools.local_broker import Mosquitto

from tests.support.fake_broker import silent_broker

ROOT = Path(__file__).resolve().parents[1]
MEASURE_S = 5.0
MAX_CORE = 0.20  # generous for a loaded machine; a spin is several times this


def test_silent_broker_costs_little_cpu_and_is_reconnected_and_reported() -> None:
    with silent_broker() as broker:
        proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "tests.support.publishing",
                broker.url,
                str(MEASURE_S + 3),
                "ack_timeout_s=1",
                "reconnect_max_s=0.5",
            ],
            cwd=ROOT,
            stdout=subprocess.PIPE,
            text=True,
        )
        try:
            assert proc.stdout is not None
            assert proc.stdout.readline().strip() == "ready"
            me = psutil.Process(proc.pid)
            before, started = me.cpu_times(), time.monotonic()
            time.sleep(MEASURE_S)
            after, ended = me.cpu_times(), time.monotonic()
            out, _ = proc.communicate(timeout=30)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait(5)
        connects, swallowed = broker.connects, broker.publishes
    cpu = (after.user + after.system - before.user - before.system) / (ended - started)
    assert cpu < MAX_CORE, f"{cpu:.0%} of a core"
    result = json.loads(out.strip().splitlines()[-1])
    # Reconnected on its policy (a second after each unanswered publish, plus backoff),
    # and never taken for connected: no publish was ever acknowledged.
    assert connects >= 3, connects
    assert swallowed >= connects
    assert result["connects"] == 0
    assert result["published"] == 0
    assert result["state"] == "disconnected"
    assert result["last_error"].startswith("not acknowledging: no answer to a publish within 1 s")
    publish = result["health_publish"]
    assert publish["broker_not_acknowledging"] >= 2
    assert publish["broker_last_error"] == result["last_error"]


@pytest.mark.mosquitto
def test_a_working_broker_is_not_taken_for_a_silent_one() -> None:
    """The same process against mosquitto: connected, publishing, nothing unanswered."""
    with Mosquitto() as broker:
        out = subprocess.run(
            [sys.executable, "-m", "tests.support.publishing", broker.url, "3", "ack_timeout_s=1"],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=60,
            check=True,
        ).stdout
    result = json.loads(out.strip().splitlines()[-1])
    assert result["connects"] == 1
    assert result["published"] >= 30
    assert result["health_publish"]["broker_not_acknowledging"] == 0
    assert result["health_publish"]["unacknowledged"] == 0
