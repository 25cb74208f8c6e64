"""experiments/insole_transfer.py keeps each person's render through a sensor under a
key of the sensor and of the source file as it is: a person rendered again (a simulator
change) never reads another render's copy (real_vs_sim_gait.py finds them the same way)."""

from __future__ import annotations

import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "experiments"))
import insole_transfer
import pytest

ROOT = Path(__file__).resolve().parent.parent
TINY = ROOT / "tests" / "data" / "tiny" / "scotti-tiny.onnx"


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


def test_any_session_file_is_read_through_the_named_sensors(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from scotti.cli.main import main as scotti_main

    scene = tmp_path / "walk.toml"
    text = (ROOT / "sim" / "scenes" / "slow-walking.toml").read_text()
    scene.write_text(text.replace("reps = 20", "reps = 8"))
    session = tmp_path / "walk.scotti"
    assert scotti_main(["sim", str(scene), "-o", str(session)]) == 0
    monkeypatch.setattr(insole_transfer, "WORK", tmp_path / "work")
    argv = ["--people", str(session), "--every", "4", "--only", "ours", "import-gaitpdb-8"]
    assert insole_transfer.main([*argv, "--model", str(TINY)]) == 0
    out = capsys.readouterr().out
    assert "`ours` |" in out
    assert "`import-gaitpdb-8` |" in out
    rendered = list((tmp_path / "work" / "import-gaitpdb-8").glob("walk.*.ses"))
    assert len(rendered) == 1  # the file through gaitpdb's cells, beside the other renders
    # The three simulated people's doc table is not written from other files.
    with pytest.raises(SystemExit):
        insole_transfer.main([*argv, "--write", str(tmp_path / "doc.md")])
    assert "--write is for the three" in capsys.readouterr().err


def test_a_missing_session_file_is_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    assert insole_transfer.main(["--people", "/nonexistent/x.scotti", "--only", "ours"]) == 2
    assert "x.scotti: no such session file" in capsys.readouterr().err


def test_a_render_is_current_only_for_the_simulator_that_stamped_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Renders kept by the experiments (wide_rule's scenes, these people) carry a stamp
    of the simulator and the labelling convention; a change of either, or no stamp,
    makes them stale, so labels of an older convention are never scored."""
    import common

    code = tmp_path / "repo"
    (code / "models").mkdir(parents=True)
    labeller = code / "models" / "progress.py"
    labeller.write_text("CUT = 'peak'\n")
    monkeypatch.setattr(common, "ROOT", code)
    rendered = tmp_path / "walking.scotti"
    assert not common.render_is_current(rendered)  # not there
    rendered.write_bytes(b"session")
    assert not common.render_is_current(rendered)  # there, but never stamped
    common.stamp_render(rendered)
    assert common.render_is_current(rendered)
    labeller.write_text("CUT = 'landing'\n")  # the labelling convention changes
    assert not common.render_is_current(rendered)
