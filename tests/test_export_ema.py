"""``scotti train --ema``: validation, best.pt and export see a moving average of the weights."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest
import torch
from scotti.cli.main import main
from scotti.export.evaluate import evaluate
from scotti.export.train import Trainer, TrainOptions, plan_epoch

from tests.test_export_train import TINY, dataset, sessions_dir, tiny_model

pytestmark = pytest.mark.torch
__all__ = ["sessions_dir"]  # the module's fixture, shared with test_export_train

OPTS = TrainOptions(epochs=2, batch=16, chunk=4, stride=2, lr=3e-3, progress_bar=False, ema=0.9)


class _Recording(Trainer):
    """A trainer that keeps its own average of the raw weights, the textbook way."""

    expected: dict[str, torch.Tensor]

    def train_step(self, *args: object) -> tuple[float, int]:  # type: ignore[override]
        out = super().train_step(*args)  # type: ignore[arg-type]
        raw = {k: v.detach().clone() for k, v in self.model.state_dict().items()}
        if not hasattr(self, "expected"):
            self.expected = raw  # the first update copies the weights
        else:
            d = self.opts.ema
            for k, v in raw.items():
                if v.is_floating_point():  # batch norm's step counter is not averaged
                    self.expected[k] = d * self.expected[k] + (1 - d) * v
        return out


def test_the_checkpoint_holds_the_average_and_the_raw_weights_apart(
    sessions_dir: Path, tmp_path: Path
) -> None:
    ds = dataset(sessions_dir)
    trainer = _Recording(
        tiny_model(), ds, dataset(sessions_dir, "b.scotti"), OPTS, run_dir=tmp_path
    )
    trainer.fit()
    ckpt = torch.load(tmp_path / "last.pt", weights_only=True)
    assert ckpt["ema_updates"] == len(trainer.step_losses)
    for name, raw in trainer.model.state_dict().items():
        assert torch.equal(ckpt["trained_model"][name], raw), name
        if raw.is_floating_point():
            torch.testing.assert_close(ckpt["model"][name], trainer.expected[name])
    moved = [k for k, v in ckpt["model"].items() if not torch.equal(v, ckpt["trained_model"][k])]
    assert moved  # the average is not the last step's weights
    # Validation judged the average: its metrics are the average's, not the raw weights'.
    averaged = tiny_model()
    averaged.load_state_dict(ckpt["model"])
    val = evaluate(averaged, dataset(sessions_dir, "b.scotti"), OPTS.val_stride, OPTS.loss_weights)
    assert ckpt["metrics"]["val"]["loss"] == pytest.approx(val["loss"])


def test_a_resumed_average_continues_exactly(sessions_dir: Path, tmp_path: Path) -> None:
    ds = dataset(sessions_dir)
    whole = Trainer(tiny_model(), ds, None, OPTS)
    whole.fit()
    first = Trainer(tiny_model(), ds, None, OPTS, run_dir=tmp_path)
    stop_at = len(plan_epoch(ds, OPTS, 0)) + 1
    assert first.fit(max_steps=stop_at) == "stopped"
    resumed = Trainer(tiny_model(seed=5), ds, None, OPTS)
    resumed.restore(torch.load(tmp_path / "last.pt", weights_only=True))
    assert resumed.fit() == "done"
    for name, value in whole.evaluated_model.state_dict().items():
        assert torch.equal(value, resumed.evaluated_model.state_dict()[name]), name
    for name, value in whole.model.state_dict().items():
        assert torch.equal(value, resumed.model.state_dict()[name]), name


def test_without_ema_the_checkpoint_is_as_before(sessions_dir: Path, tmp_path: Path) -> None:
    trainer = Trainer(
        tiny_model(), dataset(sessions_dir), None, replace(OPTS, ema=0.0), run_dir=tmp_path
    )
    trainer.fit()
    ckpt = torch.load(tmp_path / "last.pt", weights_only=True)
    assert "trained_model" not in ckpt
    assert trainer.evaluated_model is trainer.model


def test_cli_exports_the_average_and_refuses_a_bad_decay(
    sessions_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run = tmp_path / "run"
    args = [str(sessions_dir), "-o", str(run), "--config", json.dumps(TINY), "--batch", "8"]
    args += ["--chunk", "4", "--epochs", "1", "--val-subjects", "b", "--test-fraction", "0"]
    for bad in ("1", "-0.5", "nan"):
        assert main(["train", *args, "--ema", bad]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("scotti train: --ema must be")
        assert "\n" not in err
    assert main(["train", *args, "--ema", "0.99", "--no-progress"]) == 0
    ckpt = torch.load(run / "best.pt", weights_only=True)
    assert ckpt["options"]["ema"] == 0.99
    graph = tmp_path / "tiny.onnx"
    assert main(["export", str(run / "best.pt"), "-o", str(graph)]) == 0
    # The export is of the average: the graph's weights are ckpt["model"], not the raw ones.
    import onnx
    from onnx import numpy_helper

    weights = [numpy_helper.to_array(t) for t in onnx.load(str(graph)).graph.initializer]
    head = ckpt["model"]["action_head.3.weight"].numpy()
    raw = ckpt["trained_model"]["action_head.3.weight"].numpy()
    assert any(w.shape == head.shape and (abs(w - head) < 1e-6).all() for w in weights)
    assert not any(w.shape == raw.shape and (abs(w - raw) < 1e-6).all() for w in weights)
