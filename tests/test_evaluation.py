"""``scotti eval``: labelled sessions through the daemon's streaming path, scored."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scotti.cli.main import main
from scotti.evaluation.evaluation import (
    FrameScores,
    FrameSet,
    evaluate_models,
    evaluate_sessions,
    replay_session,
    score,
)
from scotti.firmware_protocol.packets import Foot
from scotti.firmware_protocol.session import LabelRecord, read_session
from scotti.models import metrics
from scotti.models.contract import ACTIONS, NO_ACTION, NUM_ACTIONS, NUM_KEYPOINTS, STANDING
from scotti.models.input_checks import UNLOADED_FRAMES
from scotti.models.runtime import ScottiRuntime

from tests.support.export_sessions import write_session
from tests.support.sessions import synthetic_counts, write_synthetic_session

FRAMES = 90


@pytest.fixture(scope="module")
def runtime(tiny_model_path: Path) -> ScottiRuntime:
    return ScottiRuntime(tiny_model_path)


@pytest.fixture
def session(tmp_path: Path) -> Path:
    # Starts near the u16 end so that the seqs wrap inside the session.
    return write_session(tmp_path / "s.session", FRAMES, first_seq=65_520)


def test_every_labelled_frame_after_the_warm_up_is_scored(
    session: Path, runtime: ScottiRuntime
) -> None:
    replay = replay_session(session, runtime)
    assert replay.labels == FRAMES
    # T frames warm the window; the last prediction is for a time past the labels.
    assert replay.evaluated == FRAMES - runtime.window
    assert replay.predictions == replay.evaluated + 1
    assert replay.unlabelled == 1
    assert replay.window_restarts == 0


def test_each_prediction_is_scored_against_the_label_one_frame_ahead(
    session: Path, runtime: ScottiRuntime
) -> None:
    labels = read_session(session).labels
    replay = replay_session(session, runtime)
    expected = FrameSet.from_labels(labels[runtime.window :])
    np.testing.assert_array_equal(replay.frames.action_true, expected.action_true)
    np.testing.assert_array_equal(replay.frames.pose_true, expected.pose_true)


def test_numbers_are_finite_and_labels_against_themselves_are_perfect(
    session: Path, runtime: ScottiRuntime
) -> None:
    report = evaluate_sessions([session], runtime)
    m = report["metrics"]
    for key in ("mpjpe_mm", "mpjae_deg", "action_accuracy", "progress_mse", "app"):
        assert math.isfinite(m[key]), key
    assert sum(map(sum, report["confusion"]["matrix"])) == m["frames_action"]

    perfect = score(FrameScores.of(FrameSet.from_labels(read_session(session).labels)))["metrics"]
    assert perfect["mpjpe_mm"] == 0.0
    assert perfect["mpjae_deg"] == 0.0
    assert perfect["action_accuracy"] == 1.0
    assert perfect["progress_mse"] == 0.0
    assert perfect["app"] == pytest.approx(1.0)


def test_standing_is_scored_as_an_action_and_its_progress_left_out() -> None:
    standing, squat = STANDING, ACTIONS.index("squat")
    kp = np.zeros((NUM_KEYPOINTS, 3), dtype=np.float32)
    labels = [
        LabelRecord(seq=i, t_ns=i, keypoints=kp, action=a, progress=p, rep=0)
        for i, (a, p) in enumerate(
            [(squat, 0.2), (squat, 0.6), (standing, 0.5), (standing, 0.5), (NO_ACTION, 0.5)]
        )
    ]
    truth = FrameSet.from_labels(labels)
    # A number in a label file on a standing or transition frame is not a progress label.
    np.testing.assert_array_equal(np.isnan(truth.progress_true), [False, False, True, True, True])
    predicted = FrameSet(
        truth.pose_pred,
        truth.pose_true,
        np.array([squat, standing, standing, squat, standing]),
        truth.action_true,
        np.array([0.3, 0.6, 0.9, 0.1, 0.0]),
        truth.progress_true,
    )
    report = score(FrameScores.of(predicted))
    assert np.shape(report["confusion"]["matrix"]) == (NUM_ACTIONS, NUM_ACTIONS)
    assert report["confusion"]["matrix"][standing][standing] == 1
    assert report["confusion"]["matrix"][standing][squat] == 1
    still = report["per_action"]["standing"]
    assert still["frames"] == 2
    assert still["action_accuracy"] == 0.5
    assert still["frames_progress"] == 0
    assert math.isnan(still["progress_mse"])
    assert report["per_action"]["transition"]["frames"] == 1
    overall = report["metrics"]
    assert overall["frames_progress"] == 2  # the two squat frames only
    assert overall["progress_mse"] == pytest.approx((0.1**2 + 0.0) / 2)
    assert overall["action_accuracy"] == pytest.approx(2 / 4)  # the transition is left out


def test_random_baseline_is_near_chance(session: Path, runtime: ScottiRuntime) -> None:
    frames = FrameScores.concat([replay_session(session, runtime).scores] * 40)
    base = score(frames)["random_baseline"]
    assert 0.55 < base["app"] < 0.78  # 2/3 in expectation
    assert 0.0 < base["action_accuracy"] < 0.3  # 1/9 in expectation


def test_pooled_figures_are_those_of_every_session_s_full_poses(
    session: Path, runtime: ScottiRuntime, tmp_path: Path
) -> None:
    # Pooling keeps per-frame errors, not poses (FrameScores): the figures must not move.
    other = write_session(tmp_path / "t.session", 70, subject="s2", drop_foot={(50, 0)})
    report = evaluate_sessions([session, other], runtime)
    full = FrameSet.concat([replay_session(p, runtime).frames for p in (session, other)])
    pose_ok = np.any(np.all(np.isfinite(full.pose_true), axis=2), axis=1)
    m = report["metrics"]
    assert m["frames"] == len(full)
    poses = (full.pose_pred, full.pose_true, pose_ok)
    assert m["mpjpe_mm"] == pytest.approx(metrics.mpjpe_mm(*poses))
    assert m["mpjae_deg"] == pytest.approx(metrics.mpjae_deg(*poses))
    assert m["action_accuracy"] == metrics.action_accuracy(full.action_pred, full.action_true)
    assert m["app"] == pytest.approx(metrics.app(full.progress_pred, full.progress_true))
    assert report["ood"]["predictions"] == sum(s["predictions"] for s in report["sessions"])


def test_cli_json_and_plots(
    session: Path, tiny_model_path: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    plots = tmp_path / "plots"
    args = ["eval", str(session), "--model", str(tiny_model_path), "--json", "--plots", str(plots)]
    assert main(args) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["metrics"]["frames"] == FRAMES - 40
    for name in ("precision-margin.png", "confusion.png"):
        assert (plots / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_cli_text_report(
    session: Path, tiny_model_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["eval", str(session), "--model", str(tiny_model_path)]) == 0
    out = capsys.readouterr().out
    assert "MPJPE" in out
    assert "random baseline" in out


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda p: p / "missing.session", "no such file"),
        (lambda p: (p / "x.txt").write_text("hello") and p / "x.txt", "not a session file"),
    ],
)
def test_user_mistakes_are_one_line(
    make: object, message: str, tmp_path: Path, tiny_model_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    path = make(tmp_path)  # type: ignore[operator]
    assert main(["eval", str(path), "--model", str(tiny_model_path)]) == 2
    err = capsys.readouterr().err
    assert message in err
    assert err.count("\n") == 1


def test_a_bad_model_is_one_line(
    session: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"not onnx")
    assert main(["eval", str(session), "--model", str(bad)]) == 2
    assert capsys.readouterr().err.count("\n") == 1


def test_several_models_on_one_replay_match_one_at_a_time(
    session: Path, runtime: ScottiRuntime, tiny_model_path: Path
) -> None:
    other = ScottiRuntime(tiny_model_path)
    both = evaluate_models([session], [runtime, other])
    alone = evaluate_sessions([session], runtime)
    assert len(both) == 2
    for report in both:
        assert report["metrics"] == alone["metrics"]
        assert report["confusion"] == alone["confusion"]


# --- --every K: sampled prediction times through the window graph ------------------


@pytest.fixture
def gapped_session(tmp_path: Path) -> Path:
    # Both feet silent for 20 frames (> 1 s): the window restarts mid-session.
    silent = {(k, foot) for k in range(60, 80) for foot in (0, 1)}
    return write_session(tmp_path / "gap.session", 150, first_seq=65_500, drop_foot=silent)


def test_every_k_samples_the_streaming_predictions_through_the_window_graph(
    gapped_session: Path, runtime: ScottiRuntime
) -> None:
    full = replay_session(gapped_session, runtime)
    sampled = replay_session(gapped_session, runtime, every=3)
    assert full.window_restarts == sampled.window_restarts == 1
    assert (full.pairs, full.labels) == (sampled.pairs, sampled.labels)
    expected = full.made[2::3]  # the 3rd, 6th, ... prediction since the session began
    assert [m.ext for m in sampled.made] == [m.ext for m in expected]
    assert sampled.predictions == len(expected) > 10
    for got, want in zip(sampled.made, expected, strict=True):
        np.testing.assert_allclose(got.pose, want.pose, atol=1e-4)
        np.testing.assert_allclose(got.probs, want.probs, atol=1e-4)
        assert got.progress == pytest.approx(want.progress, abs=1e-4)
    assert sampled.step_batches == []  # the step graph never ran
    assert sum(n for _, n in sampled.window_batches) == sampled.predictions


def test_cli_every_reports_what_was_done(
    session: Path, tiny_model_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    model = str(tiny_model_path)
    assert main(["eval", str(session), "--model", model, "--json", "--every", "4"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert (report["every"], report["graph"]) == (4, "window")
    assert "step_ms_per_row" not in report
    assert report["window_ms_per_prediction"]["windows"] == report["metrics"]["frames"]
    assert report["metrics"]["frames"] == (FRAMES - 40 + 1) // 4
    assert report["model"]["window_graph"]["path"].endswith("scotti-tiny.window.onnx")

    assert main(["eval", str(session), "--model", model, "--json", "--batch", "1"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert (report["every"], report["graph"]) == (1, "step")
    assert report["step_ms_per_row"]["rows"] == FRAMES
    assert report["step_ms_per_row"]["largest_batch"] == 1
    assert main(["eval", str(session), "--model", model, "--json"]) == 0  # batched segments
    report = json.loads(capsys.readouterr().out)
    assert (report["every"], report["graph"]) == (1, "step")
    assert report["step_ms_per_row"]["rows"] == FRAMES  # one segment: no warm-up rows

    assert main(["eval", str(session), "--model", model, "--every", "4"]) == 0
    assert "1 prediction in 4, window graph" in capsys.readouterr().out


def test_every_below_one_is_one_line(
    session: Path, tiny_model_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["eval", str(session), "--model", str(tiny_model_path), "--every", "0"]) == 2
    err = capsys.readouterr().err
    assert "--every must be at least 1" in err
    assert err.count("\n") == 1


def test_every_without_a_window_graph_is_one_line(
    session: Path, tiny_model_path: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    alone = tmp_path / "alone.onnx"
    shutil.copyfile(tiny_model_path, alone)
    assert main(["eval", str(session), "--model", str(alone), "--every", "2"]) == 2
    err = capsys.readouterr().err
    assert "alone.window.onnx" in err
    assert err.count("\n") == 1


def test_cli_defaults_to_the_shipped_model_and_leaves_out_absent_actions(
    session: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from scotti.daemon.settings import default_model_path

    assert main(["eval", str(session)]) == 0
    out = capsys.readouterr().out
    assert f"model {default_model_path()}" in out
    assert "nan" not in out
    assert "not in these sessions: " in out
    assert "MPJPE: mean per-joint position error" in out


def test_evaluation_errors_share_the_daemon_root() -> None:
    # scotti eval replays through the daemon's own path, so the CLI's one-line
    # error handling for DaemonError covers evaluation mistakes too.
    from scotti.daemon.errors import DaemonError
    from scotti.evaluation.evaluation import EvaluationError

    assert issubclass(EvaluationError, DaemonError)


def test_eval_reports_the_share_of_predictions_each_flag_withheld(
    tmp_path: Path, runtime: ScottiRuntime, capsys: pytest.CaptureFixture[str]
) -> None:
    """40 frames of a plausible map, then 40 of nobody on the insoles: the predictions
    whose newest 16 frames are all empty are unloaded, streaming and sampled alike."""
    empty = np.zeros((32, 22), np.uint16)

    def counts(foot: Foot, seq: int, i: int) -> np.ndarray:
        return synthetic_counts(foot, seq) if i < 40 else empty

    path = write_synthetic_session(tmp_path / "off.scotti", frames=80, counts_of=counts).path
    full = replay_session(path, runtime)
    assert len(full.made) == 41  # predictions for frames 40..80
    unloaded = [m.ext for m in full.made if "unloaded" in m.flags]
    assert unloaded == [m.ext for m in full.made if m.ext >= 40 + UNLOADED_FRAMES]
    sampled = replay_session(path, runtime, every=2)
    assert [m.flags for m in sampled.made] == [m.flags for m in full.made[1::2]]

    assert main(["eval", str(path), "--model", str(runtime.path), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["ood"]["predictions"] == 41
    assert report["ood"]["unloaded"] == pytest.approx(len(unloaded) / 41)
    assert report["ood"]["out_of_range"] == 0.0
    assert report["model"]["ood"]["calibrated"] is False
    assert main(["eval", str(path), "--model", str(runtime.path)]) == 0
    out = capsys.readouterr().out
    assert f"flagged (of 41 predictions): unloaded {100 * len(unloaded) / 41:.2f} %" in out
    assert "(unfamiliar: model not calibrated)" in out


def _daemon_predictions(path: Path, model: Path) -> list[Any]:
    """What ``scotti-daemon --replay`` predicts: the daemon's own Pipeline, no MQTT."""
    import asyncio

    from scotti.daemon.frames.pipeline import Pipeline, Prediction
    from scotti.daemon.input.sources import ReplaySource
    from scotti.daemon.service.counters import Counters

    out: list[Prediction] = []

    async def go() -> None:
        pipeline = Pipeline(ReplaySource(path, speed="max"), ScottiRuntime(model), Counters())
        await pipeline.run(out.append, lambda _: None, asyncio.Event())

    asyncio.run(go())
    return out


@pytest.mark.parametrize("noisy", [False, True])
def test_eval_predicts_exactly_what_the_daemon_publishes(
    tmp_path: Path, runtime: ScottiRuntime, tiny_model_path: Path, noisy: bool
) -> None:
    # The evaluation's own loop over the session (bulk reading, its decoder, assembler,
    # pairing and window) against the daemon's pipeline on the same bytes: the same
    # predictions, value for value, also with line noise between the packets.
    from tests.support.sessions import write_synthetic_session

    path = write_synthetic_session(
        tmp_path / "n.scotti", frames=FRAMES, seq_start=65_500, garbage_every=7 if noisy else 0
    ).path
    daemon = _daemon_predictions(path, tiny_model_path)
    made = replay_session(path, runtime).made
    assert len(made) == len(daemon) == FRAMES - runtime.window + 1
    for ours, theirs in zip(made, daemon, strict=True):
        assert (ours.ext - 1) % 65536 == theirs.left_seq
        np.testing.assert_array_equal(ours.pose, theirs.pose)
        np.testing.assert_array_equal(ours.probs, theirs.action_probs)
        assert ours.progress == theirs.progress or (math.isnan(theirs.progress))


# --- sessions without labels: nothing to score, what the model made of them ---------


@pytest.fixture
def unlabelled(tmp_path: Path) -> Path:
    return write_synthetic_session(tmp_path / "live.scotti", frames=FRAMES, labels=False).path


def test_eval_without_labels_says_so_once_and_reports_what_it_can(
    unlabelled: Path, tiny_model_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["eval", str(unlabelled), "--model", str(tiny_model_path)]) == 0
    out = capsys.readouterr().out
    assert out.count("nothing to score: no session has labels") == 1
    assert "nan" not in out.lower()
    assert "MPJPE" not in out  # no table of figures there are none of
    assert "confusion" not in out
    predictions = FRAMES - 40 + 1
    assert f"{predictions} predictions from {FRAMES} paired frames, 0 of them degraded" in out
    assert f"flagged (of {predictions} predictions): unloaded " in out
    assert "actions published (" in out


def test_eval_json_without_labels_has_null_metrics_and_the_counts(
    unlabelled: Path, runtime: ScottiRuntime, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["eval", str(unlabelled), "--model", str(runtime.path), "--json"]) == 0
    captured = capsys.readouterr()
    assert "NaN" not in captured.out
    report = json.loads(captured.out)
    assert "scotti eval: nothing to score: no session has labels" in captured.err
    assert report["scored"] is False
    assert report["unlabelled_sessions"] == [str(unlabelled)]
    for key in ("mpjpe_mm", "mpjae_deg", "action_accuracy", "progress_mse", "app"):
        assert report["metrics"][key] is None, key
    assert report["random_baseline"]["app"] is None
    # What the model made of it: every prediction counted once, published or withheld,
    # each published one under its most likely action (the daemon's rule).
    made = replay_session(unlabelled, runtime).made
    assert report["predictions"] == report["ood"]["predictions"] == len(made) > 0
    assert sum(report["actions_predicted"].values()) + report["actions_withheld"] == len(made)
    expected = {name: 0 for name in ACTIONS}
    for m in made:
        if not {"unloaded", "out_of_range", "unfamiliar"} & set(m.flags):
            expected[ACTIONS[int(np.argmax(m.probs))]] += 1
    assert report["actions_predicted"] == expected
    assert (report["pairs"], report["degraded_pairs"]) == (FRAMES, 0)
    assert report["rate"]["paired_frames"] == FRAMES


def test_eval_of_labelled_and_unlabelled_files_scores_the_labelled_and_names_the_others(
    session: Path,
    unlabelled: Path,
    runtime: ScottiRuntime,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    alone = evaluate_sessions([session], runtime)
    model = str(runtime.path)
    plots = tmp_path / "plots"
    args = ["eval", str(session), str(unlabelled), "--model", model, "--json"]
    assert main([*args, "--plots", str(plots)]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["scored"] is True
    assert report["unlabelled_sessions"] == [str(unlabelled)]
    assert report["metrics"]["frames"] == alone["metrics"]["frames"] == FRAMES - 40
    assert report["metrics"]["action_accuracy"] == alone["metrics"]["action_accuracy"]
    assert report["predictions"] == 2 * (FRAMES - 40 + 1)
    assert (plots / "confusion.png").is_file()

    assert main(["eval", str(session), str(unlabelled), "--model", model]) == 0
    out = capsys.readouterr().out
    assert f"not scored, no labels: {unlabelled}\n" in out
    assert "nothing to score:" not in out  # (the legend explains "-" with those words)
    assert "MPJPE" in out


def test_no_figures_are_drawn_without_labels(
    unlabelled: Path, tiny_model_path: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    plots = tmp_path / "plots"
    args = ["eval", str(unlabelled), "--model", str(tiny_model_path), "--plots", str(plots)]
    assert main(args) == 0
    assert "nothing to score" in capsys.readouterr().out
    assert not plots.exists()


def test_figures_that_exist_are_refused_unless_force(
    session: Path, tiny_model_path: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    plots = tmp_path / "plots"
    plots.mkdir()
    (plots / "confusion.png").write_bytes(b"last week's")
    args = ["eval", str(session), "--model", str(tiny_model_path), "--plots", str(plots)]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err == f"scotti eval: {plots / 'confusion.png'} exists; --force replaces it\n"
    assert (plots / "confusion.png").read_bytes() == b"last week's"
    assert not (plots / "precision-margin.png").exists()  # refused before anything ran
    assert main([*args, "--force"]) == 0
    assert (plots / "confusion.png").read_bytes()[:4] == b"\x89PNG"
