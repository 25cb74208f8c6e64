"""The fault soak at small counts: 10 unplugs, 10 broker restarts, 10 silent feet.

A real ``scotti-daemon`` process, a real mosquitto, the board emulator on a
pty; the board plays at twice the rate (the window warms up in 1.25 s) and the
silent foot lasts 1 s (twice the 0.5 s after which a foot is called silent).
"""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest
from scotti.daemon.tools import faults

pytestmark = [pytest.mark.mosquitto, pytest.mark.slow]


def test_every_fault_recovers_without_an_error_line(tiny_model_path: Path, tmp_path: Path) -> None:
    plan = faults.Plan(
        unplugs=10,
        broker_restarts=10,
        silent_feet=10,
        unplug_s=0.3,
        broker_down_s=0.3,
        silent_s=1.0,
        speed=2.0,
        model=tiny_model_path,
        log=tmp_path / "daemon.log",
    )
    results = asyncio.run(faults.FaultSoak(plan, tmp_path).run())
    table = faults.summary(results)
    log = (tmp_path / "daemon.log").read_text()
    assert len(results) == 30, table
    assert all(r.noticed for r in results), table
    assert all(r.recovered for r in results), table
    assert sum(r.errors for r in results) == 0, log
    assert "Traceback" not in log
    # A pose made before the cut never follows "receiver disconnected".
    assert sum(r.after_disconnect for r in results) == 0, table
    # One WARNING per outage, with its reason: the broker going away, the cut of the
    # receiver. (Counted by source: on a loaded host the reader may also see a stall.)
    lines = log.splitlines()
    publisher = [line for line in lines if line.startswith("WARNING scotti.daemon.mqtt.publisher")]
    # While the broker is away the queue fills: dropping the oldest is said too (rate-limited).
    broker = [line for line in publisher if "connection lost" in line]
    assert len(broker) == 10, log
    others = [line for line in publisher if "connection lost" not in line]
    assert all("dropped the oldest prediction" in line for line in others), others
    cuts = [line for line in lines if line.startswith("WARNING scotti.daemon.input.sources")]
    assert len([line for line in cuts if " lost: " in line]) == 10, log
    # The silent foot never stopped the predictions.
    assert all(r.during > 0 for r in results if r.kind == "silent foot"), table
