"""``scotti train --watch``: sessions scored after every epoch, never trained on."""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("torch")
import torch
from scotti.cli.main import main
from scotti.export.data import TrainingDataError, load_session
from scotti.export.model import Scotti, ScottiConfig
from scotti.export.train import Trainer, TrainOptions
from scotti.export.watch import Watched, load_watched, watch_line, watch_scores
from scotti.export.watch import main as watch_main
from scotti.export.windows import WindowDataset
from scotti.models.contract import ACTIONS

from tests.support.export_sessions import TINY_MODEL, label_for, write_session

pytestmark = pytest.mark.torch

TINY: dict[str, Any] = TINY_MODEL


def _history(run: Path) -> list[dict[str, Any]]:
    return [json.loads(x) for x in (run / "history.jsonl").read_text().splitlines()]


def test_every_epoch_scores_the_watched_files_with_its_weights(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, capsys: pytest.CaptureFixture[str]
) -> None:
    a = load_session(write_session(tmp_path / "a.scotti", 60, subject="a"))
    b = load_session(write_session(tmp_path / "b.scotti", 40, subject="b", first_seq=7))
    scene_path = write_session(tmp_path / "scene.scotti", 90, subject="c", first_seq=9)
    scene = load_session(scene_path)
    watched = [Watched("scene", WindowDataset([scene], 8))]
    torch.manual_seed(0)
    model = Scotti(ScottiConfig.from_dict(TINY))
    opts = TrainOptions(epochs=2, batch=16, chunk=4, patience=0, progress_bar=False)
    run = tmp_path / "run"
    run.mkdir()
    trainer = Trainer(
        model, WindowDataset([a], 8), WindowDataset([b], 8), opts, run_dir=run, watched=watched
    )
    with caplog.at_level(logging.INFO, logger="scotti.export.train"):
        trainer.fit()
    history = _history(run)
    assert [sorted(r["watch"]) for r in history] == [["scene"], ["scene"]]
    last = history[-1]["watch"]["scene"]
    # The last epoch's figures are the final weights' (no average: the model itself).
    assert last == watch_scores(trainer.evaluated_model, watched[0].windows, opts.val_stride)
    assert last["windows"] == watched[0].windows.count(opts.val_stride) > 0
    labelled = {ACTIONS[label_for(k)[1]] for k in range(8, 90) if label_for(k)[1] >= 0}
    assert set(last["recall"]) == labelled
    assert all(0.0 <= r <= 1.0 for r in last["recall"].values())
    assert 0.0 <= last["action_accuracy"] <= 1.0
    assert caplog.text.count("watch scene: accuracy") == 2
    # Validation alone picks best.pt: the record that chose it is the validation loss's.
    best = torch.load(run / "best.pt", weights_only=True)
    losses = [r["val"]["loss"] for r in history]
    assert best["epoch"] == 1 + losses.index(min(losses))
    # The command line scores a checkpoint as the run did at that epoch.
    capsys.readouterr()
    assert watch_main([str(run / "best.pt"), str(scene_path), "--stride", "4"]) == 0
    printed = capsys.readouterr().out.strip()
    assert printed == watch_line("scene", history[best["epoch"] - 1]["watch"]["scene"])
    assert watch_main([str(tmp_path / "none.pt"), str(scene_path)]) == 2
    assert "no such checkpoint" in capsys.readouterr().err


def test_a_watched_file_that_is_trained_on_is_refused(tmp_path: Path) -> None:
    a = write_session(tmp_path / "a.scotti", 60, subject="a")
    trained = [load_session(a)]
    with pytest.raises(TrainingDataError, match="--watch names training sessions"):
        load_watched([a], tmp_path / "cache", window=8, allow_invalid=False, training=trained)
    other = tmp_path / "more" / "a.scotti"
    other.parent.mkdir()
    write_session(other, 50, subject="x")
    loaded = load_watched(
        [other, tmp_path / "more"], tmp_path / "cache", window=8, allow_invalid=False,
        training=trained,
    )  # fmt: skip
    assert [w.name for w in loaded] == ["a"]  # a file named twice is watched once


def test_watch_line() -> None:
    line = watch_line(
        "squat", {"windows": 9, "action_accuracy": 0.203, "app": 0.81, "recall": {"squat": 0.17}}
    )
    assert line == "watch squat: accuracy 20.3 %, APP 0.810; recall squat 17 %"
    assert watch_line("x", {"windows": 0}) == "watch x: no labelled windows"


@pytest.mark.slow
def test_cli_watch(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    data = tmp_path / "data"
    data.mkdir()
    for who in ("s1", "s2", "s3"):
        write_session(data / f"{who}.scotti", 50, subject=who)
    scene = write_session(tmp_path / "squat.scotti", 70, subject="scene")
    run = tmp_path / "run"
    args = [str(data), "-o", str(run), "--config", json.dumps(TINY), "--batch", "8", "--chunk"]
    args += ["4", "--stride", "4", "--test-subjects", "s3", "--no-progress", "--epochs", "1"]
    assert main(["train", *args, "--watch", str(data / "s1.scotti")]) == 2
    assert "--watch names training sessions" in capsys.readouterr().err
    assert not (run / "last.pt").exists()
    assert main(["train", *args, "--watch", str(scene)]) == 0
    assert _history(run)[0]["watch"]["squat"]["windows"] > 0
