"""--keep-near: a fine-tune's pooled vectors held near its --init weights' (export/anchor.py)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("torch")
import numpy as np
import torch
from scotti.cli.main import main
from scotti.export.anchor import Anchor, relative_distance
from scotti.export.data import load_session
from scotti.export.evaluate import chunked_outputs_pooled
from scotti.export.model import Scotti
from scotti.export.rng_state import rng_state
from scotti.export.train import Trainer, TrainOptions
from scotti.export.windows import WindowDataset

from tests.support.export_sessions import TINY_MODEL, tiny_model, write_session

pytestmark = pytest.mark.torch

TINY: dict[str, Any] = TINY_MODEL


def frames_of(path: Path, start: int, count: int) -> torch.Tensor:
    session = load_session(path)
    return torch.from_numpy(session.frames[start : start + count].astype(np.float32))


def test_relative_distance_is_zero_for_the_same_vectors_and_scale_free() -> None:
    torch.manual_seed(0)
    ref, moved = torch.randn(6, 16), torch.randn(6, 16)
    assert float(relative_distance(ref, ref)) == 0.0
    d = float(relative_distance(moved, ref))
    assert d > 0.5  # two independent draws are far apart
    assert float(relative_distance(3 * moved, 3 * ref)) == pytest.approx(d, rel=1e-5)
    assert torch.isfinite(relative_distance(moved, torch.zeros(6, 16)))  # an untrained reference


def test_the_term_is_zero_at_the_start_and_pulls_only_the_trained_model(tmp_path: Path) -> None:
    write_session(tmp_path / "a.scotti", 80, subject="a")
    frames = [frames_of(tmp_path / "a.scotti", 0, TINY["window"] + 6)]
    model = tiny_model(0)
    anchor = Anchor(model, weight=1.0)
    model.train()
    # Without dropout on either side the same weights are at distance 0, though the
    # model is in training mode (dropout on) and stays so.
    assert float(anchor.term(model, frames, stride=2).detach()) == 0.0
    assert model.training
    with torch.no_grad():
        model.pool_weights.add_(torch.linspace(-1, 1, model.pool_weights.numel()))
    term = anchor.term(model, frames, stride=2)
    assert float(term.detach()) > 0.0
    term.backward()  # type: ignore[no-untyped-call]
    assert model.pool_weights.grad is not None
    assert model.pool_weights.grad.abs().sum() > 0
    assert all(p.grad is None for p in anchor.model.parameters())  # the reference stays put


def _drift(model: Scotti, reference: Scotti, frames: list[torch.Tensor]) -> float:
    model.eval()
    reference.eval()
    with torch.no_grad():
        _, pooled = chunked_outputs_pooled(model, frames, TINY["window"], 2)
        _, ref = chunked_outputs_pooled(reference, frames, TINY["window"], 2)
    return float(relative_distance(pooled, ref))


def test_a_fine_tune_with_the_pull_stays_nearer_its_start(tmp_path: Path) -> None:
    write_session(tmp_path / "a.scotti", 160, subject="a")
    data = WindowDataset([load_session(tmp_path / "a.scotti")], window=TINY["window"])
    frames = [frames_of(tmp_path / "a.scotti", 0, 120)]
    start = tiny_model(3)
    opts = TrainOptions(epochs=2, batch=8, chunk=4, lr=3e-3, progress_bar=False, seed=5)
    drifts = {}
    for weight in (0.0, 100.0):
        model = tiny_model(3)
        anchor = Anchor(start, weight) if weight else None
        trainer = Trainer(model, data, None, opts, anchor=anchor)
        trainer.fit(max_steps=12)
        drifts[weight] = _drift(model, start, frames)
        if anchor is not None:
            assert len(trainer.anchor_terms) == len(trainer.step_losses) > 1
            assert trainer.anchor_terms[0] == 0.0  # the first step starts at the reference
    assert drifts[0.0] > 0.0
    assert drifts[100.0] < 0.5 * drifts[0.0], drifts


def test_cli_keep_near_needs_init_records_its_term_and_resumes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    write_session(tmp_path / "a.scotti", 80, subject="a")
    base = [str(tmp_path / "a.scotti"), "--batch", "8", "--chunk", "4"]
    first = tmp_path / "runs" / "first"
    tiny_config = ["--config", json.dumps(TINY)]
    assert main(["train", *base, "--epochs", "1", "-o", str(first), *tiny_config]) == 0
    capsys.readouterr()
    lone = ["train", *base, "--epochs", "1", "-o", str(tmp_path / "r"), "--keep-near", "1"]
    assert main([*lone, *tiny_config]) == 2
    assert "give --init" in capsys.readouterr().err
    assert main([*lone, "--init", str(first / "last.pt"), "--keep-near", "-1"]) == 2
    assert "--keep-near must be at least 0" in capsys.readouterr().err

    second = tmp_path / "runs" / "second"
    tuned = ["--init", str(first / "last.pt"), "--keep-near", "5", "-o", str(second)]
    assert main(["train", *base, "--epochs", "1", *tuned]) == 0
    # A resumed run reads its reference again from where --init pointed.
    assert main(["train", *base, "--epochs", "2", *tuned, "--resume"]) == 0
    history = [json.loads(line) for line in (second / "history.jsonl").read_text().splitlines()]
    assert [r["epoch"] for r in history] == [1, 2]
    for record in history:
        assert record["keep_near"]["weight"] == 5.0
        assert record["keep_near"]["distance"] >= 0.0
    assert history[1]["keep_near"]["distance"] > 0.0  # the weights have moved by then
    ckpt = torch.load(second / "last.pt", weights_only=True)
    assert ckpt["options"]["keep_near"] == 5.0


def test_the_matched_pass_replays_the_training_pass_exactly(tmp_path: Path) -> None:
    """Same weights, same dropout masks, same batch statistics: 0 though dropout is on;
    the generator and the reference's running statistics are left as they were."""
    write_session(tmp_path / "a.scotti", 80, subject="a")
    frames = [frames_of(tmp_path / "a.scotti", 0, TINY["window"] + 6)]
    model = tiny_model(0, dropout=0.3)  # masks to replay
    anchor = Anchor(model, weight=1.0, pass_="matched")
    buffers = {k: b.clone() for k, b in anchor.model.named_buffers()}
    model.train()
    before = rng_state(torch.device("cpu"))
    _, pooled = chunked_outputs_pooled(model, frames, TINY["window"], 2)
    after = torch.get_rng_state()
    assert float(anchor.matched_term(model, frames, 2, pooled, before).detach()) == 0.0
    assert torch.equal(torch.get_rng_state(), after)  # training draws on as it would have
    for k, b in anchor.model.named_buffers():
        assert torch.equal(b, buffers[k]), k
    # Another draw of the masks is not the same pass: dropout alone moves the vectors,
    # which is what the eval pass avoided and the matched pass replays away.
    _, other = chunked_outputs_pooled(model, frames, TINY["window"], 2)
    assert float(relative_distance(other.detach(), pooled.detach())) > 0.0
    with torch.no_grad():
        model.pool_weights.add_(torch.linspace(-1, 1, model.pool_weights.numel()))
    before = rng_state(torch.device("cpu"))
    _, pooled = chunked_outputs_pooled(model, frames, TINY["window"], 2)
    term = anchor.matched_term(model, frames, 2, pooled, before)
    assert float(term.detach()) > 0.0
    term.backward()  # type: ignore[no-untyped-call]
    assert model.pool_weights.grad is not None
    assert model.pool_weights.grad.abs().sum() > 0
    assert all(p.grad is None for p in anchor.model.parameters())


def test_a_matched_pull_keeps_a_fine_tune_nearer_its_start(tmp_path: Path) -> None:
    write_session(tmp_path / "a.scotti", 160, subject="a")
    data = WindowDataset([load_session(tmp_path / "a.scotti")], window=TINY["window"])
    frames = [frames_of(tmp_path / "a.scotti", 0, 120)]
    start = tiny_model(3, dropout=0.3)
    # The norm on its own statistics, as a fine-tune of a graph runs it: the pull holds
    # the training pass, and inference (what _drift reads) then differs only by dropout.
    opts = TrainOptions(
        epochs=2, batch=8, chunk=4, lr=3e-3, progress_bar=False, seed=5, norm_statistics="kept"
    )
    drifts, first_losses = {}, {}
    for weight in (0.0, 100.0):
        model = tiny_model(3, dropout=0.3)
        anchor = Anchor(start, weight, pass_="matched") if weight else None
        trainer = Trainer(model, data, None, opts, anchor=anchor)
        trainer.fit(max_steps=12)
        drifts[weight] = _drift(model, start, frames)
        first_losses[weight] = trainer.step_losses[0]
        if anchor is not None:
            assert len(trainer.anchor_terms) == len(trainer.step_losses) > 1
            assert trainer.anchor_terms[0] == 0.0  # the replay of the first step is exact
            assert trainer.anchor_terms[-1] > 0.0
    # The replay leaves the generator as it was: the first step's loss (its dropout
    # masks, its batch) is the same with and without the pull.
    assert first_losses[100.0] == first_losses[0.0]
    assert drifts[100.0] < 0.5 * drifts[0.0], drifts


def test_an_unknown_pass_is_refused() -> None:
    with pytest.raises(ValueError, match="keep-near-pass"):
        Anchor(tiny_model(0), 1.0, pass_="train")
