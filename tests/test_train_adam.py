"""Adam's fused CPU kernel: chosen on the CPU, and its checkpoints and the default
(foreach) kernel's resume with each other, each process keeping its own kernel."""

from __future__ import annotations

import io
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("torch")
import torch
from scotti.export.data import load_session
from scotti.export.model import Scotti, ScottiConfig
from scotti.export.train import Trainer, TrainOptions, adam, load_optimizer_state
from scotti.export.windows import WindowDataset

from tests.support.export_sessions import TINY_MODEL, write_session

pytestmark = pytest.mark.torch

TINY: dict[str, Any] = TINY_MODEL
OPTS = TrainOptions(epochs=1, batch=8, chunk=4, stride=2, lr=1e-3, progress_bar=False)


def tiny_model() -> Scotti:
    torch.manual_seed(0)
    return Scotti(ScottiConfig.from_dict(TINY))


def round_trip(state: dict[str, Any]) -> dict[str, Any]:
    """Through torch.save and a weights-only load, as a checkpoint goes."""
    buffer = io.BytesIO()
    torch.save(state, buffer)
    buffer.seek(0)
    loaded: dict[str, Any] = torch.load(buffer, weights_only=True)
    return loaded


def steps(model: Scotti, optimizer: torch.optim.Optimizer, count: int, seed: int) -> None:
    # Batch norm in eval mode: in training mode the bias before it has a gradient of
    # rounding noise only, which Adam blows up to whole steps of either sign.
    model.eval()
    g = torch.Generator().manual_seed(seed)
    for _ in range(count):
        frames = torch.rand(2, TINY["window"], 32, 44, generator=g) * 500
        optimizer.zero_grad()
        out = model(frames)
        loss = out.pose.square().sum() + out.action_logits.square().sum() + out.progress.sum()
        loss.backward()  # type: ignore[no-untyped-call]
        optimizer.step()


def test_the_cpu_gets_the_fused_kernel() -> None:
    model = tiny_model()
    optimizer = adam(list(model.parameters()), torch.device("cpu"), lr=1e-3, weight_decay=0.0)
    assert optimizer.param_groups[0]["fused"] is True


@pytest.mark.parametrize(("saved_fused", "loaded_fused"), [(True, False), (False, True)])
def test_a_checkpoint_of_one_kernel_resumes_with_the_other(
    saved_fused: bool, loaded_fused: bool
) -> None:
    cpu = torch.device("cpu")
    first = tiny_model()
    saving = adam(list(first.parameters()), cpu, lr=1e-3, weight_decay=1e-4, fused=saved_fused)
    steps(first, saving, 3, seed=1)
    state = round_trip(saving.state_dict())

    second = tiny_model()
    second.load_state_dict(first.state_dict())
    params = list(second.parameters())
    loading = adam(params, cpu, lr=1e-3, weight_decay=1e-4, fused=loaded_fused)
    load_optimizer_state(loading, state)
    assert bool(loading.param_groups[0]["fused"]) is loaded_fused  # its own kernel kept
    for p_saved, p_loaded in zip(first.parameters(), params, strict=True):
        for key in ("exp_avg", "exp_avg_sq", "step"):
            assert torch.equal(saving.state[p_saved][key], loading.state[p_loaded][key]), key

    before = [p.detach().clone() for p in params]
    steps(first, saving, 2, seed=2)
    steps(second, loading, 2, seed=2)
    for p_saved, p_loaded in zip(first.parameters(), params, strict=True):
        # The kernels round differently; a step moves a weight by up to lr = 1e-3.
        torch.testing.assert_close(p_loaded, p_saved, rtol=0.0, atol=1e-6)
    assert any(not torch.equal(p, b) for p, b in zip(params, before, strict=True))


def test_a_trainer_resumes_a_default_kernel_checkpoint_with_the_fused_one(tmp_path: Path) -> None:
    write_session(tmp_path / "a.scotti", 110, subject="a")
    ds = WindowDataset([load_session(tmp_path / "a.scotti")], window=TINY["window"])
    opts = replace(OPTS, epochs=2)
    whole = Trainer(tiny_model(), ds, None, opts)
    whole.fit()

    first = Trainer(tiny_model(), ds, None, opts, run_dir=tmp_path / "run")
    assert first.fit(max_steps=3) == "stopped"
    ckpt = torch.load(tmp_path / "run" / "last.pt", weights_only=True)
    # The same state as the default kernel writes it (an older run's checkpoint).
    params = list(tiny_model().parameters())
    default = adam(params, torch.device("cpu"), lr=1.0, weight_decay=0.0, fused=False)
    load_optimizer_state(default, ckpt["optimizer"])
    ckpt["optimizer"] = round_trip(default.state_dict())
    assert not ckpt["optimizer"]["param_groups"][0]["fused"]

    resumed = Trainer(tiny_model(), ds, None, opts)
    resumed.restore(ckpt)
    assert resumed.optimizer.param_groups[0]["fused"] is True
    assert resumed.fit() == "done"
    assert resumed.step_losses == whole.step_losses[3:]
    for name, value in whole.model.state_dict().items():
        assert torch.equal(resumed.model.state_dict()[name], value), name
