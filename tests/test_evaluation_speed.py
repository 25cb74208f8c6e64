"""``python -m scotti.evaluation.speed``: configurations of ``scotti eval`` in turns, one
table row each; a run that fails is one line."""

from __future__ import annotations

from pathlib import Path

import pytest
from scotti.evaluation.speed import main

from tests.support.export_sessions import write_session


def test_each_configuration_is_a_row(
    tmp_path: Path, tiny_model_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    session = write_session(tmp_path / "s.ses", 120)
    model = f"--model {tiny_model_path}"
    configs = ["--config", f"{model} --jobs 1", "--config", f"{model} --jobs 2 --batch 2"]
    assert main([str(session), *configs, "--repeats", "1"]) == 0
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| `")]
    assert len(rows) == 2
    assert "--jobs 1` |" in rows[0]
    assert "--jobs 2 --batch 2` |" in rows[1]
    for row in rows:
        fps = float(row.split("|")[2].replace(",", ""))
        assert fps > 0


def test_a_failing_run_is_one_line(
    tmp_path: Path, tiny_model_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    session = write_session(tmp_path / "s.ses", 60)
    config = f"--model {tiny_model_path} --batch 0"
    assert main([str(session), "--config", config, "--repeats", "1"]) == 2
    err = capsys.readouterr().err
    assert "--batch must be at least 1" in err
    assert err.count("\n") == 1
