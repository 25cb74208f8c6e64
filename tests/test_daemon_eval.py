"""``scotti eval``: labelled sessions through the daemon's streaming path, scored."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from scotti.cli.main import main
from scotti.daemon.evaluation import (
    FrameSet,
    evaluate_models,
    evaluate_sessions,
    replay_session,
    score,
)
from scotti.firmware_protocol.session import read_session
from scotti.models.runtime import ScottiRuntime

from tests.support.export_sessions import write_session

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

    perfect = score(FrameSet.from_labels(read_session(session).labels))["metrics"]
    assert perfect["mpjpe_mm"] == 0.0
    assert perfect["mpjae_deg"] == 0.0
    assert perfect["action_accuracy"] == 1.0
    assert perfect["progress_mse"] == 0.0
    assert perfect["app"] == pytest.approx(1.0)


def test_random_baseline_is_near_chance(session: Path, runtime: ScottiRuntime) -> None:
    frames = FrameSet.concat([replay_session(session, runtime).frames] * 40)
    base = score(frames)["random_baseline"]
    assert 0.55 < base["app"] < 0.78  # 2/3 in expectation
    assert 0.0 < base["action_accuracy"] < 0.3  # 1/8 in expectation


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
