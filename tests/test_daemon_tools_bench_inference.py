"""The inference bench: frames that pass the input checks and frames that do not, and a
table whose model share is part of the whole."""

from __future__ import annotations

from pathlib import Path

import pytest
from scotti.daemon.tools.bench_inference import main, measure, random_frames, sim_frames
from scotti.models.input_checks import frame_stats
from scotti.models.runtime import ScottiRuntime


def test_sim_frames_pass_the_input_checks_and_random_ones_do_not() -> None:
    sim = frame_stats(sim_frames(4.0))
    assert len(sim.outside_share) >= 60
    assert not sim.implausible.any()
    assert sim.loaded.all()
    assert frame_stats(random_frames(16)).implausible.all()


def test_measure_splits_each_turn_into_the_model_and_the_rest(tiny_model_path: Path) -> None:
    runtime = ScottiRuntime(tiny_model_path)
    values = measure(runtime, random_frames(64), 3, max_batch=2, turns=4, repeats=2)
    assert len(values) == 2
    for total, model in values:
        assert 0 < model < total


def test_main_prints_one_row_per_kind_and_device_count(
    tiny_model_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["--model", str(tiny_model_path), "--devices", "1", "2", "--repeats", "1"]
    assert main([*argv, "--frames-per-repeat", "4"]) == 0
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| this")]
    assert [row.split(" | ")[1:3] for row in rows] == [
        ["sim", "1"],
        ["sim", "2"],
        ["random", "1"],
        ["random", "2"],
    ]
