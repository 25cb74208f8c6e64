"""``scotti calibrate`` on a streaming-native export: the held-out replay runs through the
key/value step graph, the map goes into the metadata of its step and window graphs, and
``KvStepRuntime`` then applies it to every prediction as ``ScottiRuntime`` does."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("torch")
import onnx
from scotti.cli.main import main
from scotti.evaluation.evaluation import replay_session
from scotti.export.onnx_export import Checkpoint, export_model
from scotti.models.contract import META_PROGRESS_CALIBRATION
from scotti.models.kv_streaming import KvStepRuntime, open_step_model
from scotti.models.runtime import ScottiRuntime, window_graph_for

from tests.support.export_sessions import write_session
from tests.test_export_streaming_native import TINY_KV, spread

pytestmark = pytest.mark.torch


@pytest.fixture(scope="module")
def kv_trained_on_s1(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny streaming-native export whose card says it was trained on subject s1."""
    from scotti.export.model import Scotti

    out = tmp_path_factory.mktemp("kv-calibrate") / "kv.onnx"
    split = {"split": {"train_subjects": ["s1"]}}
    export_model(Checkpoint(model=spread(Scotti(TINY_KV), 4), training_data=split), out)
    return out


def _carried(path: Path) -> str | None:
    props = {p.key: p.value for p in onnx.load(str(path), load_external_data=False).metadata_props}
    return props.get(META_PROGRESS_CALIBRATION)


def test_scotti_calibrate_writes_a_streaming_native_export_and_its_runtime_applies_it(
    tmp_path: Path, kv_trained_on_s1: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    model = kv_trained_on_s1
    window = window_graph_for(model)
    held_out = write_session(tmp_path / "s9.scotti", 1500, subject="s9")
    trained = write_session(tmp_path / "s1.scotti", 200, subject="s1")

    assert main(["calibrate", str(model), str(trained)]) == 2
    assert "trained on them" in capsys.readouterr().err
    assert (_carried(model), _carried(window)) == (None, None)  # nothing written

    assert main(["calibrate", str(model), str(held_out)]) == 0
    assert "MSE" in capsys.readouterr().out
    text = _carried(model)
    assert text is not None
    assert _carried(window) == text  # the same map in both graphs
    step = open_step_model(model)
    assert isinstance(step, KvStepRuntime)
    cal = step.progress_calibration
    assert cal is not None
    assert step.progress_calibration_info()["summary"]["fitted_on"] == ["s9"]
    assert ScottiRuntime(window).progress_calibration is not None

    raw_runtime = open_step_model(model, calibrate_progress=False)
    assert isinstance(raw_runtime, KvStepRuntime)
    assert raw_runtime.progress_calibration_info() == {
        "calibrated": False,
        "reason": "switched off",
    }
    raw = replay_session(held_out, raw_runtime).frames
    got = replay_session(held_out, step).frames
    np.testing.assert_array_equal(got.action_pred, raw.action_pred)
    want = cal.apply(raw.progress_pred, raw.action_pred)
    np.testing.assert_allclose(got.progress_pred, want, atol=1e-6)
    assert not np.allclose(got.progress_pred, raw.progress_pred)


def test_calibrate_refuses_the_window_graph_of_a_streaming_native_export(
    kv_trained_on_s1: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    held_out = write_session(tmp_path / "s9.scotti", 100, subject="s9")
    window = window_graph_for(kv_trained_on_s1)
    assert main(["calibrate", str(window), str(held_out)]) == 2
    assert "give the step graph" in capsys.readouterr().err


def test_a_streaming_checkpoint_is_scored_as_partition_runs_scores_a_run(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """export --calibrate (the kv graphs, the unfamiliar score), calibrate, eval --json:
    experiments/partition_runs.py's score() on a ``--form streaming`` run's best.pt."""
    import torch
    from scotti.export.model import Scotti
    from scotti.models.contract import META_GRAPH
    from scotti.models.kv_contract import KV_GRAPH

    split = {"train_subjects": ["s1"], "validation_subjects": ["s9"]}
    ckpt = tmp_path / "best.pt"
    state = spread(Scotti(TINY_KV), 5).state_dict()
    config = TINY_KV.to_dict()
    torch.save({"config": config, "model": state, "training_data": {"split": split}}, ckpt)
    sessions = tmp_path / "sessions"
    sessions.mkdir()
    trained = write_session(sessions / "s1.scotti", 400, subject="s1")
    held_out = write_session(sessions / "s9.scotti", 1500, subject="s9")
    test = write_session(tmp_path / "s7.scotti", 300, subject="s7")
    model = tmp_path / "models" / "scotti-ship.onnx"
    export = ["export", str(ckpt), "-o", str(model), "--calibrate", str(trained), str(held_out)]
    assert main([*export, "--force"]) == 0
    assert "unfamiliar score: threshold" in capsys.readouterr().out
    meta = {p.key: p.value for p in onnx.load(str(model), load_external_data=False).metadata_props}
    assert meta[META_GRAPH] == KV_GRAPH
    step = open_step_model(model)
    assert isinstance(step, KvStepRuntime)
    assert step.ood is not None
    assert main(["calibrate", str(model), str(held_out)]) == 0
    assert open_step_model(model).progress_calibration_info()["summary"]["fitted_on"] == ["s9"]
    capsys.readouterr()
    assert main(["eval", str(test), "--model", str(model), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert (report["model"]["step_kind"], report["subjects"]) == ("kv_cache", ["s7"])
    assert report["model"]["ood"]["calibrated"] is True
