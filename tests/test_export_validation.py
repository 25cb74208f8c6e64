"""Validation drawn from the training subjects, early stopping on its plateau, old runs."""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("torch")
import torch
from scotti.cli.main import main
from scotti.export.checkpoint import save_checkpoint
from scotti.export.data import TrainingDataError, load_session
from scotti.export.early_stop import plateau
from scotti.export.model import Scotti, ScottiConfig
from scotti.export.train import Trainer, TrainOptions
from scotti.export.validation import three_way_split
from scotti.export.windows import WindowDataset

from tests.support.export_sessions import TINY_MODEL, write_session

pytestmark = pytest.mark.torch

TINY: dict[str, Any] = TINY_MODEL
SUBJECTS = [f"s{i:02d}" for i in range(10)]


@pytest.fixture(scope="module")
def ten_subjects(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("ten")
    for who in SUBJECTS:
        write_session(d / f"{who}.scotti", 40, subject=who)
    return d


def test_validation_comes_from_the_training_subjects_never_the_test_ones(
    ten_subjects: Path,
) -> None:
    sessions = [load_session(p) for p in sorted(ten_subjects.iterdir())]
    split = three_way_split(sessions, test_subjects=["s08", "s09"], seed=3)
    assert split.test_subjects == ["s08", "s09"]
    assert len(split.validation_subjects) == 1  # 15 % of 8 rounds to 1: at least one
    assert not set(split.validation_subjects) & set(split.test_subjects)
    assert sorted(split.train_subjects + split.validation_subjects) == SUBJECTS[:8]
    assert {s.subject for s in split.train} == set(split.train_subjects)
    # Drawn with the seed: the same seed, the same subject; over seeds, not always one.
    again = three_way_split(sessions, test_subjects=["s08", "s09"], seed=3)
    assert again.validation_subjects == split.validation_subjects
    drawn = {three_way_split(sessions, seed=s).validation_subjects[0] for s in range(8)}
    assert len(drawn) > 1
    named = three_way_split(sessions, test_subjects=["s09"], val_subjects=["s00", "s01"])
    assert (named.validation_subjects, named.validation_kind) == (["s00", "s01"], "subject")
    with pytest.raises(TrainingDataError, match="are test subjects too"):
        three_way_split(sessions, test_subjects=["s09"], val_subjects=["s09"])
    with pytest.raises(TrainingDataError, match="unknown validation subject"):
        three_way_split(sessions, val_subjects=["nobody"])


def test_one_training_subject_validates_on_the_end_of_its_sessions(tmp_path: Path) -> None:
    a = load_session(write_session(tmp_path / "a.scotti", 100, subject="a"))
    b = load_session(write_session(tmp_path / "b.scotti", 100, subject="b"))
    split = three_way_split([a, b], test_subjects=["b"], val_fraction=0.2)
    assert (split.validation_kind, split.test_subjects) == ("time", ["b"])
    assert len(split.train[0]) == 80
    assert split.validation[0].seq[0] == a.seq[80]
    assert [s.subject for s in split.test] == ["b"]


def test_plateau_is_a_function_of_the_validation_losses() -> None:
    def history(*losses: float) -> list[dict[str, Any]]:
        return [{"epoch": i + 1, "val": {"loss": v}} for i, v in enumerate(losses)]

    rising = plateau(history(3.0, 2.0, 1.0, 1.0005, 0.9995, 1.2), patience=3, min_delta=1e-3)
    assert (rising.best_epoch, rising.stale_epochs, rising.reached) == (3, 3, True)
    assert not plateau(history(3.0, 2.0, 1.0, 1.2), patience=3, min_delta=1e-3).reached
    assert not plateau(history(3.0, 3.0, 3.0, 3.0), patience=0, min_delta=0.0).reached
    assert plateau([{"epoch": 1, "train_loss": 1.0}], patience=1, min_delta=0.0).best_epoch == 0


def test_a_run_stops_on_its_plateau_and_says_so(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    a = load_session(write_session(tmp_path / "a.scotti", 60, subject="a"))
    b = load_session(write_session(tmp_path / "b.scotti", 40, subject="b", first_seq=7))
    torch.manual_seed(0)
    model = Scotti(ScottiConfig.from_dict(TINY))
    # lr 0: the validation loss cannot move, so every epoch after the first is stale.
    opts = TrainOptions(epochs=20, batch=16, chunk=4, lr=0.0, patience=2, progress_bar=False)
    train, val = WindowDataset([a], 8), WindowDataset([b], 8)
    trainer = Trainer(model, train, val, opts, run_dir=tmp_path / "run")
    (tmp_path / "run").mkdir()
    with caplog.at_level(logging.INFO, logger="scotti.export.train"):
        assert trainer.fit() == "plateau"
    history = [json.loads(x) for x in (tmp_path / "run" / "history.jsonl").read_text().splitlines()]
    assert [r["epoch"] for r in history] == [1, 2, 3]
    assert history[-1]["status"] == "plateau"
    assert (history[-1]["best_epoch"], history[-1]["stale_epochs"]) == (1, 2)
    assert "plateau" in caplog.text
    assert "best epoch 1" in caplog.text
    assert torch.load(tmp_path / "run" / "best.pt", weights_only=True)["epoch"] == 1


def test_a_run_that_ends_its_epochs_says_so(tmp_path: Path) -> None:
    a = load_session(write_session(tmp_path / "a.scotti", 60, subject="a"))
    b = load_session(write_session(tmp_path / "b.scotti", 40, subject="b", first_seq=7))
    torch.manual_seed(0)
    model = Scotti(ScottiConfig.from_dict(TINY))
    opts = TrainOptions(epochs=2, batch=16, chunk=4, patience=0, progress_bar=False)
    run = tmp_path / "run"
    run.mkdir()
    Trainer(model, WindowDataset([a], 8), WindowDataset([b], 8), opts, run_dir=run).fit()
    history = [json.loads(x) for x in (run / "history.jsonl").read_text().splitlines()]
    # Only the last epoch carries it: a reader tells the schedule's end from a time budget.
    assert [r.get("status") for r in history] == [None, "epochs done"]


@pytest.mark.slow
def test_cli_three_way_split_and_an_old_runs_resume(
    ten_subjects: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run = tmp_path / "run"
    args = [str(ten_subjects), "-o", str(run), "--config", json.dumps(TINY), "--batch", "8"]
    args += ["--chunk", "4", "--stride", "4", "--test-subjects", "s08", "s09", "--no-progress"]
    assert main(["train", *args, "--epochs", "1"]) == 0
    ckpt = torch.load(run / "last.pt", weights_only=True)
    split = ckpt["training_data"]["split"]
    assert split["test_subjects"] == ["s08", "s09"]
    assert len(split["validation_subjects"]) == 1
    assert len(split["train_subjects"]) == 7
    # The test subjects are looked at once, at the end, into their own file.
    report = json.loads((run / "test.json").read_text())
    assert report["test_subjects"] == ["s08", "s09"]
    assert report["test"]["windows"] > 0
    assert "test" not in json.dumps(ckpt["history"])

    # A checkpoint written before runs had a validation split cannot be resumed: one line, exit 2,
    # and the checkpoint is left as it was.
    old = dict(ckpt)
    old["training_data"] = {
        **ckpt["training_data"],
        "split": {"kind": "subject", "train_subjects": SUBJECTS[:8], "test_subjects": SUBJECTS[8:]},
    }
    save_checkpoint(old, run / "last.pt")
    before = (run / "last.pt").read_bytes()
    assert main(["train", *args, "--epochs", "2", "--resume"]) == 2
    assert "predates the validation split" in capsys.readouterr().err
    assert (run / "last.pt").read_bytes() == before
