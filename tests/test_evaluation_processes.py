"""``scotti eval --processes P``: whole sessions replayed in spawned worker processes
give the report one process gives (several models, --every, the order of sessions),
add the workers' CPU time to the rate, and a user's mistake is one line, not a
traceback from a worker."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from scotti.cli.main import main
from scotti.evaluation.evaluation import evaluate_models
from scotti.evaluation.processes import GraphSpec
from scotti.models.kv_streaming import open_step_model

from tests.support.export_sessions import write_session
from tests.test_evaluation_segments import _rounded

SCORED = ("metrics", "per_action", "confusion", "ood", "sessions", "predictions")


def test_sessions_in_worker_processes_report_what_one_process_reports(
    tmp_path: Path, tiny_model_path: Path, standing_model_path: Path
) -> None:
    # Three sessions of different lengths, two models on one replay of each.
    paths = [write_session(tmp_path / f"s{n}.ses", n, first_seq=65_400 + n) for n in (530, 90, 410)]
    runtimes = [open_step_model(tiny_model_path), open_step_model(standing_model_path)]
    seen: list[list[str]] = [[], []]
    one, two = (
        evaluate_models(
            paths,
            runtimes,
            processes=processes,
            on_session=lambda _i, _n, p, _s, k=k: seen[k].append(p.name),
        )
        for k, processes in enumerate((1, 2))
    )
    assert seen[0] == seen[1] == ["s530.ses", "s90.ses", "s410.ses"]
    for mine, theirs in zip(two, one, strict=True):
        assert [s["path"] for s in mine["sessions"]] == [str(p) for p in paths]
        for key in SCORED:
            assert _rounded(mine[key]) == _rounded(theirs[key]), key
        assert mine["rate"]["paired_frames"] == theirs["rate"]["paired_frames"] == 1030
        assert mine["rate"]["processes"] == 2
        # The workers' CPU is counted: the model's time alone is more than this
        # process spent outside waiting on them.
        assert mine["rate"]["cpu_seconds"] >= mine["rate"]["model_cpu_seconds"] > 0
    # The two models' reports differ (the second always says standing): not one report twice.
    assert two[0]["actions_predicted"] != two[1]["actions_predicted"]


def test_every_kth_prediction_through_the_window_graph_in_workers(
    tmp_path: Path, tiny_model_path: Path
) -> None:
    paths = [write_session(tmp_path / f"s{n}.ses", n, first_seq=n) for n in (300, 260)]
    runtime = open_step_model(tiny_model_path)
    one = evaluate_models(paths, [runtime], every=4)[0]
    two = evaluate_models(paths, [runtime], every=4, processes=2)[0]
    assert two["every"] == 4
    for key in SCORED:
        assert _rounded(two[key]) == _rounded(one[key]), key


def test_a_worker_opens_the_graph_with_the_parents_progress_switch(
    tiny_model_path: Path,
) -> None:
    on = open_step_model(tiny_model_path)
    off = open_step_model(tiny_model_path, calibrate_progress=False)
    assert GraphSpec.of(off).calibrate_progress is False
    assert GraphSpec.of(on).calibrate_progress is (on.progress_calibration is not None)
    assert GraphSpec.of(on).path == Path(tiny_model_path)


def test_cli_processes_and_its_mistakes(
    tmp_path: Path, tiny_model_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    good = write_session(tmp_path / "good.ses", 200)
    model = str(tiny_model_path)
    assert main(["eval", str(good), "--model", model, "--json", "--processes", "2"]) == 0
    run = capsys.readouterr()
    assert json.loads(run.out)["rate"]["processes"] == 2
    assert "2 processes" in run.err
    assert main(["eval", str(good), "--model", model, "--processes", "0"]) == 2
    err = capsys.readouterr().err
    assert "--processes must be at least 1" in err
    assert err.count("\n") == 1
    # A truncated session file fails in a worker: one line naming it, no traceback.
    broken = tmp_path / "broken.ses"
    broken.write_bytes(good.read_bytes()[:37])
    code = main(["eval", str(good), str(broken), "--model", model, "--processes", "2"])
    err = capsys.readouterr().err
    assert code == 2
    assert "Traceback" not in err
    assert "broken.ses" in err


def test_a_worker_that_cannot_open_the_model_is_one_error(
    tmp_path: Path, tiny_model_path: Path
) -> None:
    import shutil

    from scotti.evaluation.errors import EvaluationError

    model = tmp_path / "scotti-tiny.onnx"
    shutil.copy(tiny_model_path, model)
    runtime = open_step_model(model)  # opened here, then gone before the workers open it
    model.unlink()
    paths = [write_session(tmp_path / f"s{n}.ses", n) for n in (120, 130)]
    with pytest.raises(EvaluationError, match="worker process ended while replaying s120"):
        evaluate_models(paths, [runtime], processes=2)
