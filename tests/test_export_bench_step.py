"""``python -m scotti.export.bench_step --model``: an exported model's step beside its
int8 copy, at each batch size, on real insole frames of a session."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scotti.export.bench_step import main, step_inputs
from scotti.models.runtime import ScottiRuntime

from tests.support.export_sessions import write_session


def test_model_mode_times_both_graphs_at_each_batch(
    tmp_path: Path, tiny_model_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    session = write_session(tmp_path / "s.ses", 120)
    argv = ["--model", str(tiny_model_path), "--batches", "1", "4", "--threads", "1"]
    assert main([*argv, "--frames", "3", "--session", str(session)]) == 0
    out = capsys.readouterr().out
    rows = [
        line for line in out.splitlines() if line.startswith("| fp32") or line.startswith("| int8")
    ]
    assert [r.split("|")[1:4] for r in rows] == [
        [f" {graph} ", " 1 ", f" {b} "] for graph in ("fp32", "int8") for b in (1, 4)
    ]
    assert rows[0].endswith("| 1.00x; 1.00x |")  # fp32 against itself
    assert "int8: " in out  # the copy made for the run
    # fp32 rows do not see each other; dynamic int8 scales each call's activations at once.
    assert "fp32: one call of 4 frames against 4 calls of one: pose moves up to 0.00 mm" in out
    int8 = next(line for line in out.splitlines() if line.startswith("int8: one call"))
    assert float(int8.split("up to ")[1].split(" mm")[0]) > 0


def test_session_inputs_are_frames_with_their_own_embeddings(
    tmp_path: Path, tiny_model_path: Path
) -> None:
    runtime = ScottiRuntime(tiny_model_path)
    session = write_session(tmp_path / "s.ses", 100)
    frames, past = step_inputs(runtime, 5, session)
    assert frames.shape == (5, *runtime.frame_shape)
    assert past.shape == (5, runtime.window - 1, runtime.embed_dim)
    assert frames.dtype == past.dtype == np.float32
    # The newest cached embedding is the previous frame's: not random numbers.
    assert np.abs(past).max() < 1e3
    assert not np.array_equal(past[0], past[-1])


def test_too_short_a_session_is_one_line(
    tmp_path: Path, tiny_model_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    session = write_session(tmp_path / "s.ses", 30)
    argv = ["--model", str(tiny_model_path), "--batches", "8", "--session", str(session)]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "fewer than T + 8" in err
    assert err.count("\n") == 1
