"""Training: chunked = naive, a tiny model overfits, resume is exact, the CLI end to end."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("torch")
import torch
from scotti.cli.main import main
from scotti.export.data import load_session
from scotti.export.evaluate import chunked_outputs, evaluate
from scotti.export.losses import scotti_loss
from scotti.export.model import Scotti, ScottiConfig
from scotti.export.run_dir import RunExistsError, check_run_dir, clear_run
from scotti.export.train import (
    Trainer,
    TrainingDivergedError,
    TrainOptions,
    batch_tensors,
    plan_epoch,
    unfold_frames,
)
from scotti.export.windows import WindowDataset
from scotti.models import contract

from tests.support.export_sessions import PERIOD, TINY_MODEL, write_session

pytestmark = pytest.mark.torch

TINY: dict[str, Any] = TINY_MODEL


@pytest.fixture(scope="module")
def sessions_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("train_sessions")
    write_session(d / "a.scotti", 110, subject="a", first_seq=65500)
    write_session(d / "b.scotti", 60, subject="b", drop_foot=[(20, 0)])
    return d


@pytest.fixture(autouse=True)
def _one_thread() -> None:
    torch.set_num_threads(1)


def tiny_model(seed: int = 0, **changes: object) -> Scotti:
    torch.manual_seed(seed)
    return Scotti(ScottiConfig.from_dict({**TINY, **changes}))


def dataset(sessions_dir: Path, name: str = "a.scotti") -> WindowDataset:
    return WindowDataset([load_session(sessions_dir / name)], window=TINY["window"])


@pytest.mark.parametrize("stride", [1, 3])
def test_chunked_embedding_equals_naive_windows(sessions_dir: Path, stride: int) -> None:
    ds = dataset(sessions_dir)
    model = tiny_model(embed_dim=32, heads=4).eval()
    opts = TrainOptions(batch=12, chunk=5, stride=stride, max_shift=2)
    batch = plan_epoch(ds, opts, epoch=0)[0]
    frames, targets = batch_tensors(ds, batch)
    with torch.no_grad():
        chunked = chunked_outputs(model, frames, model.cfg.window, stride)
        naive = model(torch.cat([unfold_frames(f, model.cfg.window, stride) for f in frames]))
    assert chunked.pose.shape[0] == targets.action.shape[0] >= opts.batch
    for a, b in zip(chunked, naive, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-5)


@pytest.mark.slow
def test_standing_windows_are_trained_on_as_often_as_they_occur(tmp_path: Path) -> None:
    """No window is dropped or oversampled for its action: an epoch at stride 1 visits
    every usable window once, standing ones included; their progress stays out of the loss."""
    path = write_session(tmp_path / "s.scotti", 9 * PERIOD + TINY["window"] + 4)
    ds = WindowDataset([load_session(path)], window=TINY["window"])
    usable = ds.sessions[0].action[ds.starts(0) + ds.window]
    assert (usable == contract.STANDING).sum() >= PERIOD - 1
    opts = TrainOptions(epochs=1, batch=8, chunk=4, stride=1, progress_bar=False)
    planned = np.concatenate(
        [ds.targets(p.chunk).action for batch in plan_epoch(ds, opts, 0) for p in batch]
    )
    np.testing.assert_array_equal(np.sort(planned), np.sort(usable))
    counts = ds.target_counts()  # what scotti train logs and the card records
    assert counts["standing"] == (usable == contract.STANDING).sum()
    assert counts["transition"] == (usable == contract.NO_ACTION).sum()
    assert sum(counts.values()) == usable.size == len(ds)
    batch = next(
        b
        for b in plan_epoch(ds, opts, 0)
        if any((ds.targets(p.chunk).action == contract.STANDING).any() for p in b)
    )
    frames, targets = batch_tensors(ds, batch)
    still = targets.action == contract.STANDING
    assert bool(torch.isnan(targets.progress[still]).all())
    model = tiny_model()
    loss, parts = scotti_loss(chunked_outputs(model, frames, ds.window, 1), targets)
    loss.backward()  # type: ignore[no-untyped-call]
    assert all(bool(torch.isfinite(v)) for v in parts.values())
    assert all(p.grad is None or bool(torch.isfinite(p.grad).all()) for p in model.parameters())


def test_a_tiny_model_overfits_a_tiny_data_set(sessions_dir: Path) -> None:
    session = load_session(sessions_dir / "a.scotti").slice(0, 56)  # 48 windows
    ds = WindowDataset([session], window=TINY["window"])
    model = tiny_model(embed_dim=32, head_hidden=32, conv_channels=[8, 8])
    opts = TrainOptions(epochs=200, batch=48, chunk=8, stride=1, lr=1e-2, max_shift=0)
    trainer = Trainer(model, ds, None, replace_progress(opts))
    assert trainer.fit() == "done"
    losses = [r["train_loss"] for r in trainer.state.history]
    assert losses[-1] < 0.3 * losses[0], losses[::20]
    # Predicting the mean pose scores about 140 mm here: the model learnt the frames.
    assert evaluate(model, ds, stride=1)["mpjpe_mm"] < 80.0


def replace_progress(opts: TrainOptions) -> TrainOptions:
    from dataclasses import replace

    return replace(opts, progress_bar=False)


def test_resume_continues_exactly_like_an_uninterrupted_run(
    sessions_dir: Path, tmp_path: Path
) -> None:
    ds = dataset(sessions_dir)
    # Dropout on, so the restored torch RNG matters too.
    opts = replace_progress(TrainOptions(epochs=2, batch=16, chunk=4, stride=2, lr=1e-3))
    whole = Trainer(tiny_model(dropout=0.2), ds, None, opts)
    whole.fit()

    first = Trainer(tiny_model(dropout=0.2), ds, None, opts, run_dir=tmp_path)
    stop_at = len(plan_epoch(ds, opts, 0)) + 2  # mid-way through the second epoch
    assert first.fit(max_steps=stop_at) == "stopped"
    ckpt = torch.load(tmp_path / "last.pt", weights_only=True)
    assert (ckpt["epoch"], ckpt["step_in_epoch"]) == (1, 2)

    resumed = Trainer(tiny_model(seed=99, dropout=0.2), ds, None, opts)
    resumed.restore(ckpt)
    assert resumed.fit() == "done"
    assert first.step_losses == whole.step_losses[:stop_at]
    assert resumed.step_losses == whole.step_losses[stop_at:]
    assert resumed.state.history[-1]["train_loss"] == whole.state.history[-1]["train_loss"]
    for name, value in whole.model.state_dict().items():
        assert torch.equal(value, resumed.model.state_dict()[name]), name


@pytest.mark.slow
def test_cli_trains_resumes_and_exports(
    sessions_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run = tmp_path / "runs" / "tiny"
    common = [str(sessions_dir), "-o", str(run), "--config", json.dumps(TINY)]
    common += ["--batch", "8", "--chunk", "4", "--stride", "2"]
    common += ["--val-subjects", "b", "--test-fraction", "0"]  # two subjects: no test set
    assert main(["train", *common, "--epochs", "1"]) == 0
    assert main(["train", *common, "--epochs", "2", "--resume"]) == 0
    ckpt = torch.load(run / "last.pt", weights_only=True)
    assert ckpt["epoch"] == 2
    assert ckpt["config"]["window"] == TINY["window"]
    data = ckpt["training_data"]
    assert data["split"]["validation_subjects"] == ["b"]
    assert data["split"]["test_subjects"] == []
    assert len(data["files"]) == 2
    assert data["problems"]["missing_left"] == 1
    val = ckpt["metrics"]["val"]
    assert val["windows"] > 0
    assert np.isfinite(val["mpjpe_mm"])
    assert 0 <= val["app"] <= 1
    history = (run / "history.jsonl").read_text().splitlines()
    assert [json.loads(line)["epoch"] for line in history] == [1, 2]
    assert (run / "best.pt").is_file()
    assert list((tmp_path / "runs" / ".session-cache").glob("*.npz"))

    if importlib.util.find_spec("scotti.export.export_cli") is None:
        pytest.skip("export_cli is not built yet")
    out = tmp_path / "models" / "tiny.onnx"
    assert main(["export", str(run / "last.pt"), "-o", str(out)]) == 0
    assert out.is_file()


@pytest.mark.slow
def test_a_run_directory_that_holds_a_run_takes_resume_or_force(
    sessions_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run = tmp_path / "run"
    common = [str(sessions_dir), "-o", str(run), "--config", json.dumps(TINY), "--epochs", "1"]
    common += ["--batch", "8", "--chunk", "4", "--stride", "4", "--val-subjects", "b"]
    common += ["--test-fraction", "0", "--no-progress"]
    assert main(["train", *common]) == 0
    first = (run / "last.pt").read_bytes()
    capsys.readouterr()
    assert main(["train", *common, "--seed", "1"]) == 2
    err = capsys.readouterr().err
    held = "last.pt, best.pt, history.jsonl"
    assert err == (
        f"scotti train: {run} holds a run ({held}); --resume goes on from it, --force starts over\n"
    )
    assert (run / "last.pt").read_bytes() == first
    with pytest.raises(SystemExit) as exit_:
        main(["train", *common, "--resume", "--force"])
    assert exit_.value.code == 2
    assert "not allowed with argument" in capsys.readouterr().err
    # --force starts over: none of the old run's files is left (a test.json this run
    # does not write again included), the directory's other files are.
    (run / "test.json").write_text("{}")
    (run / "notes.txt").write_text("mine")
    assert main(["train", *common, "--seed", "1", "--force"]) == 0
    assert not (run / "test.json").exists()
    assert (run / "notes.txt").read_text() == "mine"
    ckpt = torch.load(run / "last.pt", weights_only=True)
    assert (ckpt["epoch"], ckpt["options"]["seed"]) == (1, 1)
    assert len((run / "history.jsonl").read_text().splitlines()) == 1
    assert (run / "last.pt").read_bytes() != first


def test_train_help_says_the_rule(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["train", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "is refused, unless --resume or --force" in text
    assert "--force start over in a run directory that holds a run" in text


def test_resume_needs_a_last_pt_when_the_directory_holds_a_run(tmp_path: Path) -> None:
    run = tmp_path / "run"
    check_run_dir(run, resume=False, force=False)  # not there yet: a new run
    run.mkdir()
    (run / "plan.json").write_text("{}")  # an experiment's file, no run
    check_run_dir(run, resume=False, force=False)
    check_run_dir(run, resume=True, force=False)  # nothing to resume: a new run
    (run / "best.pt").write_bytes(b"")
    for resume in (False, True):
        with pytest.raises(RunExistsError, match="--force starts over"):
            check_run_dir(run, resume=resume, force=False)
    check_run_dir(run, resume=False, force=True)
    (run / "last.pt").write_bytes(b"")
    check_run_dir(run, resume=True, force=False)
    assert clear_run(run) == ["last.pt", "best.pt"]
    assert [p.name for p in run.iterdir()] == ["plan.json"]


def test_cli_mistakes_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["train", str(tmp_path / "nothing"), "-o", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("scotti train:")
    assert "nothing" in err
    assert "\n" not in err
    assert main(["train", str(tmp_path), "-o", str(tmp_path / "r"), "--config", "huge"]) == 2
    assert "preset" in capsys.readouterr().err


def test_cli_loss_weights_make_a_single_task_run(
    sessions_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run = tmp_path / "action-only"
    args = [str(sessions_dir), "-o", str(run), "--config", json.dumps(TINY), "--epochs", "1"]
    args += ["--batch", "8", "--chunk", "4", "--val-subjects", "b", "--test-fraction", "0"]
    assert main(["train", *args, "--loss-weights", "0,1,0"]) == 0
    ckpt = torch.load(run / "last.pt", weights_only=True)
    assert ckpt["options"]["loss_weights"] == {"pose": 0.0, "action": 1.0, "progress": 0.0}
    val = ckpt["metrics"]["val"]
    # The validation loss is the weighted one: with pose and progress off it is the CE alone.
    assert val["loss"] == pytest.approx(val["loss_action"], rel=1e-5)
    assert val["loss_pose"] > 0

    for bad in ("1,2", "a,b,c", "0,0,0", "-1,1,1", "nan,1,1", "inf,1,1"):
        assert main(["train", *args, "-o", str(tmp_path / "r"), f"--loss-weights={bad}"]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("scotti train: --loss-weights")
        assert "\n" not in err
    for bad in ("0.7", "-0.01", "nan"):
        assert main(["train", *args, "-o", str(tmp_path / "r"), f"--max-crosstalk={bad}"]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("scotti train: --max-crosstalk must be between 0 and 0.5")
        assert "\n" not in err


def test_a_diverged_loss_stops_with_one_line(sessions_dir: Path) -> None:
    ds = dataset(sessions_dir)
    model = tiny_model()
    with torch.no_grad():
        for p in model.pose_head.parameters():
            p.fill_(float("nan"))  # what an exploding step leaves behind
    trainer = Trainer(model, ds, None, replace_progress(TrainOptions(epochs=1, batch=8)))
    with pytest.raises(TrainingDivergedError, match="lower --lr"):
        trainer.fit()


def test_resume_follows_the_same_files_moved_and_refuses_other_files(
    sessions_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A run trained on one machine and resumed on another finds its corpus in another
    folder: the same files below it, the same frames, so it goes on; other files do not."""
    import shutil

    first = tmp_path / "machine-a" / "corpus"
    shutil.copytree(sessions_dir, first)
    run = tmp_path / "run"
    opts = ["-o", str(run), "--config", json.dumps(TINY), "--batch", "8", "--chunk", "4"]
    opts += ["--stride", "4", "--val-subjects", "b", "--test-fraction", "0", "--no-progress"]
    assert main(["train", str(first), *opts, "--epochs", "1"]) == 0
    moved = tmp_path / "machine-b" / "data" / "corpus"
    moved.parent.mkdir(parents=True)
    shutil.move(first, moved)
    assert main(["train", str(moved), *opts, "--epochs", "2", "--resume"]) == 0
    ckpt = torch.load(run / "last.pt", weights_only=True)
    assert ckpt["epoch"] == 2
    assert all(f.startswith(str(moved)) for f in ckpt["training_data"]["files"])
    # Another set of files (one more) is refused, and so is a file of the same name
    # that holds other frames.
    more = tmp_path / "more"
    shutil.copytree(moved, more)
    write_session(more / "c.scotti", 70, subject="c")
    capsys.readouterr()
    assert main(["train", str(more), *opts, "--epochs", "3", "--resume"]) == 2
    assert "other session files" in capsys.readouterr().err
    longer = tmp_path / "longer"
    longer.mkdir()
    write_session(longer / "a.scotti", 130, subject="a", first_seq=65500)
    shutil.copy(moved / "b.scotti", longer / "b.scotti")
    assert main(["train", str(longer), *opts, "--epochs", "3", "--resume"]) == 2
    assert "other session files" in capsys.readouterr().err
    assert torch.load(run / "last.pt", weights_only=True)["epoch"] == 2


def test_the_same_files_are_told_apart_by_their_layout_and_frames() -> None:
    from scotti.export.run_data import same_session_files

    here = {"files": ["/a/c/realistic/s1.ses", "/a/c/extra/s2.ses"], "frames": 10}
    moved = {"files": ["/b/d/c/extra/s2.ses", "/b/d/c/realistic/s1.ses"], "frames": 10}
    assert same_session_files(here, moved)
    assert not same_session_files(here, {**moved, "frames": 11})
    flat = {"files": ["/b/s1.ses", "/b/s2.ses"], "frames": 10}  # the layout below differs
    assert not same_session_files(here, flat)
    mixed = {"files": ["rel/s1.ses", "/abs/s2.ses"], "frames": 10}  # no common folder
    assert same_session_files(mixed, mixed)
    assert not same_session_files(mixed, here)
