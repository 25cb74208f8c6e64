"""experiments/schema_vs_training.py: the schema's range of each field beside what
training sessions' scenes hold, read from real session files' headers."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import pytest
from scotti.firmware_protocol.session import SessionWriter
from scotti.firmware_protocol.session_records import SessionHeader
from scotti.sim.scene import Scene

EXPERIMENTS = Path(__file__).resolve().parent.parent / "experiments"
sys.path.insert(0, str(EXPERIMENTS))

import schema_vs_training  # noqa: E402


def _session(path: Path, height: float, threshold: float, noise: float) -> Path:
    scene = Scene.model_validate(
        {
            "name": path.stem,
            "subject": {"height_m": height, "mass_kg": 70.0, "style_seed": 3},
            "script": [{"action": "standing", "duration_s": 2.0}],
            "insole": {"model": "realistic", "threshold_kpa": threshold},
            "effects": [{"name": "noise", "std_counts": noise}],
        }
    )
    header = SessionHeader(
        source="simulated", device="scotti-sim", rows=32, cols=22, sample_bits=12,
        rate_hz=16.0, created_unix=0.0, scene=scene.model_dump(mode="json"), subject=None,
    )  # fmt: skip
    with SessionWriter(path, header):
        pass
    return path


def _rows(tmp_path: Path) -> dict[str, Any]:
    files = [
        _session(tmp_path / "a.ses", 1.6, 10.0, 3.0),
        _session(tmp_path / "b.ses", 1.8, 30.0, 6.0),
    ]
    found, read = schema_vs_training.rows(files, schema_vs_training.schema_fields())
    assert read == 2
    return {r.path: r for r in found}


def test_each_field_holds_the_sessions_values_against_the_schemas_range(
    tmp_path: Path,
) -> None:
    rows = _rows(tmp_path)
    height = rows["subject.height_m"]
    assert sorted(height.seen) == [1.6, 1.8]
    assert (height.low, height.high) == (1.2, 2.2)
    assert height.covered == pytest.approx(0.2)
    assert sorted(rows["insole.threshold_kpa"].seen) == [10.0, 30.0]
    assert sorted(rows["effects.noise.std_counts"].seen) == [3.0, 6.0]
    # Effects the sessions do not carry hold nothing; a trait drawn from one style
    # seed is one value (no span).
    assert rows["effects.jitter.std_ms"].seen == ()
    assert rows["effects.jitter.std_ms"].covered == 0.0
    assert rows["subject.depth"].covered == 0.0
    assert len(rows["subject.depth"].seen) == 2


def test_the_table_puts_the_least_covered_first(tmp_path: Path) -> None:
    rows = _rows(tmp_path)
    lines = schema_vs_training.table(list(rows.values()), 2)
    body = lines[2:]
    shares = [float(line.rsplit("|", 2)[1].strip(" %")) for line in body]
    assert shares == sorted(shares)
    assert any(line.startswith("| `subject.height_m` | 1.2 .. 2.2 | 1.6 .. 1.8 |") for line in body)


def test_tempo_is_measured_in_logarithm() -> None:
    line = schema_vs_training.tempo_line((0.65, 1.3), None)
    assert "30 % of the schema's span" in line
    assert "100 %" in schema_vs_training.tempo_line((0.65, 1.3), (0.3, 3.0))


def test_a_missing_training_file_is_a_usage_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exit_:
        schema_vs_training.main(["--files", str(tmp_path / "none.ses")])
    assert exit_.value.code == 2
    assert "1 of 1 training files missing" in capsys.readouterr().err
