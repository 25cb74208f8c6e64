"""Progress calibration: fitted on held-out frames, monotone, carried in the model's
metadata and applied by the runtime (models/progress_calibration.py, ``scotti calibrate``)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import onnx
import pytest
from scotti.cli.main import main
from scotti.evaluation.evaluation import replay_session
from scotti.models import metrics
from scotti.models.contract import ACTIONS, META_CARD, META_PROGRESS_CALIBRATION, STANDING
from scotti.models.errors import ModelContractError
from scotti.models.progress_calibration import ProgressCalibration, fit
from scotti.models.runtime import ScottiRuntime

from tests.support.export_sessions import write_session

SQUAT, LUNGE = ACTIONS.index("squat"), ACTIONS.index("lunge")


def _hedged(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Labels, and outputs pulled towards the middle as a squared-error head does."""
    rng = np.random.default_rng(seed)
    label = rng.uniform(0, 1, n)
    output = 0.5 + 0.6 * (label - 0.5) + rng.normal(0, 0.05, n)
    return label, output


def test_the_fit_undoes_hedging_on_fresh_frames_and_keeps_the_order() -> None:
    label, output = _hedged(4000, 0)
    action = np.full(4000, SQUAT)
    action[:100] = LUNGE  # too few to fit: left as it is
    label[:50] = np.nan  # unlabelled frames are left out of the fit
    cal = fit(output, label, action)
    assert set(cal.knots) == {SQUAT}
    fresh_label, fresh_output = _hedged(4000, 1)
    squats = np.full(4000, SQUAT)
    mapped = cal.apply(fresh_output, squats)
    before = metrics.progress_mse(fresh_output, fresh_label)
    assert metrics.progress_mse(mapped, fresh_label) < 0.5 * before
    order = np.argsort(fresh_output, kind="stable")
    assert np.all(np.diff(mapped[order]) >= 0)  # monotone: a rising output still rises
    assert np.all((mapped >= 0) & (mapped <= 1))
    lunges = np.full(10, LUNGE)
    untouched = cal.apply(fresh_output[:10], lunges)
    np.testing.assert_array_equal(untouched, fresh_output[:10].astype(np.float32))


def test_standing_gets_no_map_and_the_json_round_trips() -> None:
    label, output = _hedged(2000, 2)
    cal = fit(output, label, np.full(2000, STANDING))
    assert not cal.knots  # standing has no progress
    cal = fit(output, label, np.full(2000, SQUAT))
    back = ProgressCalibration.from_json(cal.to_json())
    x = np.linspace(0, 1, 50)
    np.testing.assert_allclose(back.apply(x, np.full(50, SQUAT)), cal.apply(x, np.full(50, SQUAT)))


@pytest.mark.parametrize(
    "text",
    [
        "not json",
        json.dumps({"maps": {"squat": {"x": [0, 1], "y": [1, 0]}}}),  # falls
        json.dumps({"maps": {"squat": {"x": [0, 1], "y": [0]}}}),
        json.dumps({"maps": {"hopping": {"x": [0], "y": [0]}}}),
    ],
)
def test_a_malformed_calibration_is_a_contract_error(text: str) -> None:
    with pytest.raises(ModelContractError):
        ProgressCalibration.from_json(text)


def _model_trained_on(tmp_path: Path, tiny_model_path: Path, subjects: list[str]) -> Path:
    """The tiny graphs, their card naming the subjects they were trained on."""
    for src in (tiny_model_path, tiny_model_path.with_name("scotti-tiny.window.onnx")):
        proto = onnx.load(str(src))
        card = {"training_data": {"split": {"train_subjects": subjects}}}
        for prop in proto.metadata_props:
            if prop.key == META_CARD:
                prop.value = json.dumps(card)
        onnx.save(proto, str(tmp_path / src.name))
    return tmp_path / tiny_model_path.name


def test_scotti_calibrate_writes_both_graphs_and_the_runtime_applies_it(
    tmp_path: Path, tiny_model_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    model = _model_trained_on(tmp_path, tiny_model_path, ["s1"])
    held_out = write_session(tmp_path / "s9.scotti", 1500, subject="s9")
    trained = write_session(tmp_path / "s1.scotti", 100, subject="s1")

    assert main(["calibrate", str(model), str(trained)]) == 2
    assert "trained on them" in capsys.readouterr().err
    assert ScottiRuntime(model).progress_calibration is None  # nothing written

    assert main(["calibrate", str(model), str(held_out)]) == 0
    assert "MSE" in capsys.readouterr().out
    step, window = ScottiRuntime(model), ScottiRuntime(model.with_name("scotti-tiny.window.onnx"))
    assert step.progress_calibration is not None
    assert window.progress_calibration is not None
    assert step.progress_calibration_info()["summary"]["fitted_on"] == ["s9"]
    # The runtime applies it to every prediction: calibrated = map(raw, argmax action).
    raw = replay_session(held_out, ScottiRuntime(model, calibrate_progress=False)).frames
    got = replay_session(held_out, step).frames
    want = step.progress_calibration.apply(raw.progress_pred, raw.action_pred)
    np.testing.assert_allclose(got.progress_pred, want, atol=1e-6)
    assert not np.allclose(got.progress_pred, raw.progress_pred)
    assert ScottiRuntime(model, calibrate_progress=False).progress_calibration_info() == {
        "calibrated": False,
        "reason": "switched off",
    }
    # scotti eval scores it either way, in this process or in a worker: the report says
    # which, and the progress figures differ by what the map does.
    capsys.readouterr()
    reports = {}
    for flags in (
        [],
        ["--no-progress-calibration"],
        ["--no-progress-calibration", "--processes", "2"],
    ):
        assert main(["eval", str(held_out), "--model", str(model), "--json", *flags]) == 0
        reports[len(flags)] = json.loads(capsys.readouterr().out)
    assert reports[0]["model"]["progress_calibration"]["calibrated"] is True
    assert reports[1]["model"]["progress_calibration"] == {
        "calibrated": False,
        "reason": "switched off",
    }
    assert reports[0]["metrics"]["progress_mse"] != reports[1]["metrics"]["progress_mse"]
    assert reports[3]["metrics"] == reports[1]["metrics"]  # the worker opened it switched off
    # An edit of the model in place, not an output: a second fit replaces the first,
    # no --force asked (the help says why).
    capsys.readouterr()
    assert main(["calibrate", str(model), str(held_out)]) == 0
    assert ScottiRuntime(model).progress_calibration_info()["summary"]["fitted_on"] == ["s9"]
    with pytest.raises(SystemExit):
        main(["calibrate", "--help"])
    assert "edited in place" in capsys.readouterr().out


def test_a_graph_with_a_broken_calibration_does_not_load(
    tmp_path: Path, tiny_model_path: Path
) -> None:
    copy = tmp_path / "broken.onnx"
    shutil.copy(tiny_model_path, copy)
    proto = onnx.load(str(copy))
    entry = proto.metadata_props.add()
    entry.key, entry.value = META_PROGRESS_CALIBRATION, "{"
    onnx.save(proto, str(copy))
    with pytest.raises(ModelContractError, match=r"broken\.onnx: .*progress calibration"):
        ScottiRuntime(copy)


def test_the_map_reaches_zero_and_one_so_every_repetition_completes() -> None:
    rng = np.random.default_rng(3)
    label = rng.uniform(0, 1, 6000)
    # A hedging head whose extreme outputs mix phases: its top bin's mean label is
    # well below 1, which an unstretched isotonic map would keep.
    output = 0.5 + 0.4 * (label - 0.5) + rng.normal(0, 0.12, 6000)
    cal = fit(output, label, np.full(6000, SQUAT))
    x, y = cal.knots[SQUAT]
    assert y[0] == 0.0
    assert y[-1] == 1.0
    assert np.all(np.diff(y) >= 0)
    # The ends are reached past the data, at outputs 0 and 1: the extreme bins keep their
    # pooled labels (moving them to 0 and 1 cost a trained model's held-out MSE).
    assert (x[0], x[-1]) == (0.0, 1.0)
    assert 0.0 < y[1] < 0.2
    assert 0.8 < y[-2] < 1.0
    assert cal.apply([output.max() + 1.0], [SQUAT])[0] == 1.0
    assert cal.apply([output.min() - 1.0], [SQUAT])[0] == 0.0


def test_a_map_without_evidence_of_progress_is_not_stretched() -> None:
    rng = np.random.default_rng(4)
    label = rng.uniform(0.4, 0.6, 3000)  # outputs carry nothing about the label
    output = rng.uniform(0, 1, 3000)
    cal = fit(output, label, np.full(3000, SQUAT))
    _, y = cal.knots[SQUAT]
    assert y[-1] - y[0] < 0.5
