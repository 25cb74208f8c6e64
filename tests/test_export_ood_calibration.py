"""``scotti export --calibrate``: the unfamiliar score's statistics in the graphs and the card."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import onnx
import pytest
from scotti.cli.main import main as scotti_main
from scotti.export.card import ood_markdown
from scotti.export.data import load_session
from scotti.export.errors import ExportError
from scotti.export.make_tiny import build_tiny
from scotti.export.onnx_export import Checkpoint, export_model
from scotti.export.ood_calibration import Calibration, calibrate, gather, split_subjects
from scotti.export.progress_fit import fit_progress
from scotti.export.validation import three_way_split
from scotti.models.contract import ACTIONS, META_OOD, OUTPUT_POOLED
from scotti.models.runtime import ScottiRuntime, load_pair
from scotti.models.streaming import StreamingWindow

from tests.support.export_sessions import write_session
from tests.support.fixtures_models import TINY_CHECKPOINT, TINY_STEP

pytestmark = pytest.mark.torch

SPLIT = {
    "split": {
        "kind": "subject",
        "train_subjects": ["a", "b"],
        "test_subjects": ["c"],
    }
}


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A tiny model exported with calibration on three small subjects' sessions."""
    tmp = tmp_path_factory.mktemp("calibrated")
    sessions = tmp / "sessions"
    sessions.mkdir()
    for subject in ("a", "b", "c"):
        write_session(sessions / f"{subject}.ses", 160, subject=subject)
    ckpt = Checkpoint(model=build_tiny().eval(), training_data=SPLIT)
    out = tmp / "models" / "cal.onnx"
    # Small sessions: an action with 10 held-out windows gets its progress map.
    request = Calibration(
        (sessions,), percentile=95.0, max_windows=60, held_out_windows=40, progress_min_windows=10
    )
    export_model(ckpt, out, calibration=request, int8=True)
    return out, sessions


@pytest.mark.slow
def test_the_graphs_carry_pooled_and_the_statistics_and_the_card_says_so(
    calibrated: tuple[Path, Path],
) -> None:
    out, _ = calibrated
    step, window = load_pair(out)
    for runtime in (step, window):
        proto = onnx.load(str(runtime.path), load_external_data=False)
        assert [o.name for o in proto.graph.output][-1] == OUTPUT_POOLED
        assert META_OOD in {p.key for p in proto.metadata_props}
        assert runtime.ood is not None
        assert runtime.ood_info()["calibrated"] is True
    ood = step.card["ood"]
    assert ood["calibrated"] is True
    assert ood["train_subjects"] == ["a", "b"]
    assert ood["held_out_subjects"] == ["c"]
    assert ood["held_out_split"] == "test"
    assert ood["threshold_percentile"] == 95.0
    # Each side thinned to its own limit (the statistics' and the thresholds').
    assert 40 < ood["train_windows"] <= 60
    assert 0 < ood["held_out_windows"] <= 40
    assert ood["input_checks"]["unloaded_force_n"] == 100.0
    card = json.loads(out.with_suffix(".card.json").read_text())
    assert card["ood"]["threshold"] == pytest.approx(step.ood.threshold)  # type: ignore[union-attr]
    assert "unfamiliar" in out.with_suffix(".card.md").read_text()


@pytest.mark.slow
def test_training_windows_fit_a_mean_per_action_where_each_has_enough(
    calibrated: tuple[Path, Path], tmp_path: Path
) -> None:
    out, _ = calibrated
    # The fixture's 60 windows a side hold under MIN_CLASS_WINDOWS of every action: one mean.
    assert ScottiRuntime(out).ood.action_means is None  # type: ignore[union-attr]
    # Longer sessions: each action's windows, by their target slot's label, get a mean.
    for subject in ("a", "b", "c"):
        write_session(tmp_path / f"{subject}.ses", 900, subject=subject)
    request = Calibration((tmp_path,), max_windows=2000)
    sets = gather(SPLIT, request)
    stats = calibrate(out.with_name("cal.window.onnx"), sets, request)
    am = stats.action_means
    assert am is not None
    assert stats.threshold == 1.0
    per_action = stats.summary["actions"]
    assert set(per_action) <= set(ACTIONS)
    assert len(per_action) == len(am.actions) >= 2
    assert [ACTIONS[a] for a in am.actions] == list(per_action)
    trained = sum(a["train_windows"] for a in per_action.values())
    assert trained < stats.summary["train_windows"]  # the stands (no action) fit none
    # Held-out windows called each action set its threshold (the graph is barely trained,
    # so some actions are called on too few and take the nearest mean's).
    assert sum(a["held_out_windows"] for a in per_action.values()) > 0
    assert stats.summary["train_subjects"] == ["a", "b"]
    # Each action's mean lies at distance 0 from itself.
    np.testing.assert_allclose(stats.score(am.means, np.array(am.actions)), 0.0, atol=1e-2)
    card = "\n".join(ood_markdown({**stats.summary, "calibrated": True}))
    first, a = next(iter(per_action.items()))
    row = f"| {first} | {a['train_windows']} | {a['held_out_windows']} | {a['threshold']:.2f} |"
    assert row in card


@pytest.mark.slow
def test_the_int8_graphs_carry_statistics_of_their_own_pooled_vectors(
    calibrated: tuple[Path, Path],
) -> None:
    out, _ = calibrated
    fp32 = ScottiRuntime(out).ood
    int8_step = ScottiRuntime(out.with_name("cal.int8.onnx")).ood
    int8_window = ScottiRuntime(out.with_name("cal.int8.window.onnx")).ood
    assert fp32 is not None
    assert int8_step is not None
    assert int8_window is not None
    # Fitted on the int8 graph's pooled vectors, not copied from fp32 ...
    assert not np.array_equal(int8_step.mean, fp32.mean)
    # ... the same in both int8 graphs, and what the card says.
    np.testing.assert_array_equal(int8_step.mean, int8_window.mean)
    card = json.loads(out.with_suffix(".card.json").read_text())
    assert card["int8_ood"]["threshold"] == pytest.approx(int8_step.threshold)
    assert card["ood"]["threshold"] == pytest.approx(fp32.threshold)
    assert f"threshold **{int8_step.threshold:.2f}**" in out.with_suffix(".card.md").read_text()


@pytest.mark.slow
def test_step_and_window_graph_score_the_same_window_alike(calibrated: tuple[Path, Path]) -> None:
    out, _ = calibrated
    step, window = load_pair(out)
    rng = np.random.default_rng(0)
    frames = rng.uniform(0, 1500, (step.window, *step.frame_shape)).astype(np.float32)
    streaming = StreamingWindow(step)
    result = None
    for f in frames:
        result = streaming.push(f)
    assert result is not None
    assert result.unfamiliar_score is not None
    batch = window.run_windows(frames[None])
    assert batch.unfamiliar_score is not None
    assert result.unfamiliar_score == pytest.approx(float(batch.unfamiliar_score[0]), rel=1e-4)


@pytest.mark.slow
def test_the_held_out_subjects_also_fit_the_progress_calibration(
    calibrated: tuple[Path, Path],
) -> None:
    out, sessions = calibrated
    step, window = load_pair(out)
    for runtime in (step, window):
        assert runtime.progress_calibration is not None
        assert runtime.progress_calibration_info()["summary"]["fitted_on"] == ["c"]
    card = step.card["progress_calibration"]
    assert card["calibrated"] is True
    assert card["mse_after"] <= card["mse_before"]
    assert "## Progress calibration" in out.with_suffix(".card.md").read_text()
    # Both graphs map the same window's progress alike (the step graph streaming).
    frames = np.random.default_rng(1).uniform(0, 1500, (step.window, *step.frame_shape))
    streaming = StreamingWindow(step)
    for f in frames.astype(np.float32):
        result = streaming.push(f)
    assert result is not None
    batch = window.run_windows(frames[None].astype(np.float32))
    assert result.progress == pytest.approx(float(batch.progress[0]), abs=1e-4)
    # Asked for none: none.
    held = [load_session(sessions / "c.ses")]
    none = Calibration((sessions,), progress_windows=0)
    assert fit_progress(out.with_name("cal.window.onnx"), held, none) is None


def test_an_uncalibrated_export_still_runs_and_says_why() -> None:
    runtime = ScottiRuntime(TINY_STEP)
    assert runtime.ood is None
    info = runtime.ood_info()
    assert info["calibrated"] is False
    assert info["reason"].startswith("not calibrated")
    frames = np.full((runtime.window, *runtime.frame_shape), 300.0, np.float32)
    window = StreamingWindow(runtime)
    results = [window.push(f) for f in frames]
    assert results[-1] is not None
    assert results[-1].unfamiliar_score is None
    assert results[-1].pooled is not None


def test_a_checkpoint_without_its_split_cannot_be_calibrated(tmp_path: Path) -> None:
    with pytest.raises(ExportError, match="does not name its training subjects"):
        split_subjects({"files": []})
    with pytest.raises(ExportError, match="no held-out subjects"):
        split_subjects({"split": {"train_subjects": ["a"]}})
    # As the trainer records it (export/validation.py): validation first, else test.
    split = {"train_subjects": ["a"], "validation_subjects": ["v"], "test_subjects": ["t"]}
    assert split_subjects({"split": split})[1:] == (["v"], "validation")
    split["validation_subjects"] = []
    assert split_subjects({"split": split})[1:] == (["t"], "test")


def test_a_run_with_a_validation_split_names_its_held_out_subjects(tmp_path: Path) -> None:
    for i in range(6):
        write_session(tmp_path / f"s{i:02d}.ses", 40, subject=f"s{i:02d}")
    sessions = [load_session(p) for p in sorted(tmp_path.iterdir())]
    splits = three_way_split(sessions, test_fraction=0.0, val_subjects=["s04", "s05"])
    train, held, which = split_subjects({"split": splits.describe()})
    assert (held, which) == (["s04", "s05"], "validation")
    assert set(train) == {"s00", "s01", "s02", "s03"}


def test_cli_calibrate_without_the_subjects_sessions_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    write_session(tmp_path / "x.ses", 80, subject="x")
    code = scotti_main(
        [
            "export",
            str(TINY_CHECKPOINT),
            "-o",
            str(tmp_path / "m.onnx"),
            "--calibrate",
            str(tmp_path),
        ]
    )
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert err.startswith("scotti export: ")
    assert "\n" not in err
    assert not (tmp_path / "m.onnx").exists()
