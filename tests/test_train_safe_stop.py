"""Stopping a training run from outside: SIGTERM finishes the step and writes last.pt,
--save-minutes bounds what SIGKILL loses, and --resume ends where an uninterrupted run does.

Real ``scotti train`` processes on a tiny corpus, real signals.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("torch")
import torch
from scotti.cli.main import main
from scotti.export.data import load_session
from scotti.export.model import Scotti, ScottiConfig
from scotti.export.stop_signals import stop_on_signals
from scotti.export.train import Trainer, TrainOptions
from scotti.export.windows import WindowDataset

from tests.support.export_sessions import TINY_MODEL, write_session

pytestmark = pytest.mark.torch

TINY: dict[str, Any] = {**TINY_MODEL, "dropout": 0.1}  # on, so the restored RNG state matters
EPOCHS = 4
EVERY_STEP = "0.00001"  # --save-minutes: well under a step, so last.pt is written before each


@pytest.fixture(scope="module")
def sessions_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("safe_stop_sessions")
    write_session(d / "a.scotti", 110, subject="a")
    write_session(d / "b.scotti", 60, subject="b")
    return d


@pytest.fixture(scope="module")
def uninterrupted(sessions_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """last.pt of the whole run, never stopped (and saving only at epoch ends)."""
    run = tmp_path_factory.mktemp("whole") / "run"
    assert main(["train", *train_args(sessions_dir, run)]) == 0
    return load(run / "last.pt")


def train_args(sessions_dir: Path, run: Path, *extra: str) -> list[str]:
    args = [str(sessions_dir), "-o", str(run), "--config", json.dumps(TINY)]
    args += ["--epochs", str(EPOCHS), "--batch", "4", "--chunk", "2", "--stride", "1"]
    args += ["--val-subjects", "b", "--test-fraction", "0", "--lr", "1e-3", "--no-progress"]
    args += ["--cache", str(sessions_dir.parent / "cache"), "--threads", "1"]
    return [*args, *extra]


def start(sessions_dir: Path, run: Path, *extra: str) -> subprocess.Popen[str]:
    command = [sys.executable, "-m", "scotti.cli.main", "train"]
    command += train_args(sessions_dir, run, "--save-minutes", EVERY_STEP, *extra)
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    return subprocess.Popen(
        command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env
    )


def load(path: Path) -> dict[str, Any]:
    ckpt: dict[str, Any] = torch.load(path, map_location="cpu", weights_only=True)
    return ckpt


def wait_for_training(proc: subprocess.Popen[str], last: Path, timeout: float = 90.0) -> None:
    """Until the run has written last.pt inside its first epoch (it is past its start)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            _, err = proc.communicate()
            pytest.fail(f"scotti train ended ({proc.returncode}) before training:\n{err[-3000:]}")
        if last.is_file():
            return
        time.sleep(0.01)
    proc.kill()
    pytest.fail("scotti train wrote no last.pt in time")


def assert_same_weights(got: dict[str, Any], want: dict[str, Any]) -> None:
    assert (got["epoch"], got["global_step"]) == (want["epoch"], want["global_step"])
    for name, value in want["model"].items():
        assert torch.equal(got["model"][name], value), name
    got_losses = [r["train_loss"] for r in got["history"]]
    assert got_losses == [r["train_loss"] for r in want["history"]]


@pytest.mark.slow
def test_sigterm_finishes_the_step_writes_last_pt_and_resume_matches(
    sessions_dir: Path, tmp_path: Path, uninterrupted: dict[str, Any]
) -> None:
    run = tmp_path / "run"
    proc = start(sessions_dir, run)
    wait_for_training(proc, run / "last.pt")
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err[-3000:]
    stopped = load(run / "last.pt")
    where = (stopped["epoch"], stopped["step_in_epoch"])
    assert stopped["global_step"] < uninterrupted["global_step"], "the run ended before SIGTERM"
    assert f"SIGTERM: stopped at epoch {where[0] + 1} step {where[1]}" in err
    assert "Traceback" not in err

    assert main(["train", *train_args(sessions_dir, run, "--resume")]) == 0
    assert_same_weights(load(run / "last.pt"), uninterrupted)


@pytest.mark.slow
def test_save_minutes_bounds_what_sigkill_loses_and_resume_matches(
    sessions_dir: Path, tmp_path: Path, uninterrupted: dict[str, Any]
) -> None:
    run = tmp_path / "run"
    proc = start(sessions_dir, run)
    wait_for_training(proc, run / "last.pt")
    # A last.pt from inside an epoch: --save-minutes wrote it, not an epoch's end.
    deadline = time.monotonic() + 60
    while load(run / "last.pt")["step_in_epoch"] == 0:
        assert time.monotonic() < deadline, "no last.pt from inside an epoch"
        time.sleep(0.01)
    proc.kill()  # SIGKILL: no handler runs, no goodbye checkpoint
    proc.communicate(timeout=60)
    killed = load(run / "last.pt")
    assert killed["global_step"] < uninterrupted["global_step"], "the run ended before SIGKILL"

    assert main(["train", *train_args(sessions_dir, run, "--resume")]) == 0
    assert_same_weights(load(run / "last.pt"), uninterrupted)


def test_saving_often_changes_no_number(sessions_dir: Path, tmp_path: Path) -> None:
    ds = WindowDataset([load_session(sessions_dir / "a.scotti")], window=TINY["window"])
    opts = TrainOptions(epochs=2, batch=8, chunk=4, stride=2, lr=1e-3, progress_bar=False)
    runs = {}
    for minutes in (0.0, float(EVERY_STEP)):
        torch.manual_seed(0)
        model = Scotti(ScottiConfig.from_dict(TINY))
        run_dir = tmp_path / f"save-{minutes}"
        trainer = Trainer(model, ds, None, replace(opts, save_minutes=minutes), run_dir=run_dir)
        trainer.fit()
        runs[minutes] = trainer
    plain, often = runs.values()
    assert often.step_losses == plain.step_losses
    for name, value in plain.model.state_dict().items():
        assert torch.equal(value, often.model.state_dict()[name]), name


def test_a_stop_request_ends_fit_before_the_next_step(sessions_dir: Path, tmp_path: Path) -> None:
    ds = WindowDataset([load_session(sessions_dir / "a.scotti")], window=TINY["window"])
    opts = TrainOptions(epochs=2, batch=8, chunk=4, stride=2, lr=1e-3, progress_bar=False)
    torch.manual_seed(0)
    trainer = Trainer(Scotti(ScottiConfig.from_dict(TINY)), ds, None, opts, run_dir=tmp_path)
    before = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGINT)}
    with stop_on_signals() as stop:
        assert trainer.fit(max_steps=3) == "stopped"
        signal.raise_signal(signal.SIGINT)  # caught: a request, no KeyboardInterrupt
        assert stop.signal_name == "SIGINT"
        assert trainer.fit(stop=stop) == "stopped"
        assert trainer.state.global_step == 3  # no step after the request
        signal.raise_signal(signal.SIGTERM)  # another signal (torchrun's after Ctrl-C): caught
        assert stop.signal_name == "SIGINT"
        with pytest.raises(KeyboardInterrupt):
            signal.raise_signal(signal.SIGINT)  # the same one again acts as usual
    assert load(tmp_path / "last.pt")["global_step"] == 3
    assert {s: signal.getsignal(s) for s in before} == before


@pytest.mark.slow
def test_under_torchrun_a_signal_to_one_rank_stops_both_with_last_pt(
    sessions_dir: Path, tmp_path: Path
) -> None:
    psutil = pytest.importorskip("psutil")
    run = tmp_path / "run"
    args = train_args(sessions_dir, run, "--save-minutes", EVERY_STEP, "--device", "cpu")
    command = [sys.executable, "-m", "torch.distributed.run", "--standalone"]
    command += ["--nproc-per-node", "2", "-m", "scotti.cli.main", "train", *args]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    proc = subprocess.Popen(
        command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env
    )
    wait_for_training(proc, run / "last.pt", timeout=120.0)
    ranks = {
        child.environ().get("RANK"): child for child in psutil.Process(proc.pid).children(True)
    }
    ranks["1"].send_signal(signal.SIGTERM)  # rank 1 alone: rank 0 must stop with it
    _, err = proc.communicate(timeout=120)
    if proc.returncode != 0:  # the rare gloo abort at exit (tests/test_export_distributed.py)
        assert "terminate called without an active exception" in err, err[-4000:]
    assert "a signal to another rank: stopped at epoch" in err  # rank 0 logs, and saved
    stopped = load(run / "last.pt")
    assert stopped["world_size"] == 2
    assert stopped["epoch"] < EPOCHS
