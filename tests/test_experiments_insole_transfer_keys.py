"""experiments/insole_transfer.py keeps each person's render through a sensor under a
key of the sensor and of the source file as it is: a person rendered again (a simulator
change) never reads another render's copy (real_vs_sim_gait.py finds them the same way)."""

from __future__ import annotations

import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "experiments"))
import insole_transfer


def _sensor(name: str) -> insole_transfer.ForeignSensor:
    (entry,) = [s for s in insole_transfer.sensors() if s.name == name]
    assert entry.sensor is not None
    return entry.sensor


def test_a_source_rendered_again_gets_a_new_key(tmp_path: Path) -> None:
    source = tmp_path / "subject-200.ses"
    source.write_bytes(b"first render")
    sensor = _sensor("grid-16x8")
    before = insole_transfer.render_path(source, sensor, "grid-16x8")
    assert insole_transfer.render_path(source, sensor, "grid-16x8") == before  # stable
    source.write_bytes(b"second render, another simulator")
    os.utime(source, ns=(1, 1))
    after = insole_transfer.render_path(source, sensor, "grid-16x8")
    assert after != before
    assert after.parent == before.parent
    assert after.name.startswith("subject-200.")


def test_each_sensor_has_its_own_key(tmp_path: Path) -> None:
    source = tmp_path / "subject-200.ses"
    source.write_bytes(b"a render")
    one = insole_transfer.render_path(source, _sensor("grid-16x8"), "x")
    other = insole_transfer.render_path(source, _sensor("grid-8x4"), "x")
    assert one != other
