"""Fine-tuning: --init from a checkpoint (a grown action head included), --freeze."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("torch")
import torch
from scotti.cli.main import main
from scotti.export.data import load_session
from scotti.export.errors import ExportError
from scotti.export.losses import LossWeights
from scotti.export.model import Scotti, ScottiConfig
from scotti.export.train import Trainer, TrainOptions, freeze_parts, load_initial_weights
from scotti.export.windows import WindowDataset

from tests.support.export_sessions import TINY_MODEL, tiny_model, write_session

pytestmark = pytest.mark.torch

TINY: dict[str, Any] = TINY_MODEL


def test_init_copies_weights_and_keeps_known_action_rows() -> None:
    source, target = tiny_model(1), tiny_model(2)
    state = {k: v.clone() for k, v in source.state_dict().items()}
    # A checkpoint from before the contract grew: one action fewer.
    state["action_head.3.weight"] = state["action_head.3.weight"][:-1]
    state["action_head.3.bias"] = state["action_head.3.bias"][:-1]
    fresh_last_row = target.action_head[3].weight[-1].detach().clone()
    notes = load_initial_weights(target, state)
    assert len(notes) == 2
    assert torch.equal(target.cnn.conv1.weight, source.cnn.conv1.weight)
    w = target.action_head[3].weight
    assert torch.equal(w[:-1], source.action_head[3].weight[:-1])
    assert torch.equal(w[-1], fresh_last_row)  # the new action starts fresh
    state["pose_head.3.weight"] = state["pose_head.3.weight"][:, :-1]
    with pytest.raises(ExportError, match=r"pose_head\.3\.weight"):
        load_initial_weights(target, state)


def test_frozen_parts_do_not_move(tmp_path: Path) -> None:
    write_session(tmp_path / "a.scotti", 80, subject="a")
    data = WindowDataset([load_session(tmp_path / "a.scotti")], window=TINY["window"])
    model = tiny_model(0)
    before = {k: v.clone() for k, v in model.state_dict().items()}
    opts = TrainOptions(epochs=1, batch=8, chunk=4, progress_bar=False, freeze=("encoder",))
    trainer = Trainer(model, data, None, opts)
    trainer.fit(max_steps=3)
    after = model.state_dict()
    for name in ("class_token", "positions", "pool_weights", "encoder.0.attn.qkv.weight"):
        assert torch.equal(before[name], after[name]), name
    assert not torch.equal(before["cnn.conv1.weight"], after["cnn.conv1.weight"])
    assert not torch.equal(before["pose_head.0.weight"], after["pose_head.0.weight"])
    with pytest.raises(ExportError, match="the parts are cnn, encoder, pose_head"):
        freeze_parts(model, ["heads"])


@pytest.mark.parametrize("arch", ["paper", "streaming"])
def test_only_the_progress_head_moves_when_the_rest_is_frozen(tmp_path: Path, arch: str) -> None:
    """Fine-tuning one task: the other outputs stay bit for bit what they were, in either
    form (the streaming form keeps its layers and relative biases in another module)."""
    write_session(tmp_path / "a.scotti", 80, subject="a")
    data = WindowDataset([load_session(tmp_path / "a.scotti")], window=TINY["window"])
    torch.manual_seed(0)
    model = Scotti(ScottiConfig.from_dict({**TINY, "arch": arch}))
    before = {k: v.clone() for k, v in model.state_dict().items()}
    rest = ("cnn", "encoder", "pose_head", "action_head")
    # Weight decay on: it would move a head whose loss weight is 0 but that is not frozen.
    opts = TrainOptions(
        epochs=1, batch=8, chunk=4, progress_bar=False, freeze=rest,
        loss_weights=LossWeights(pose=0, action=0, progress=1),
        weight_decay=0.1,
    )  # fmt: skip
    Trainer(model, data, None, opts).fit(max_steps=3)
    after = model.state_dict()
    moved = sorted(k for k in before if not torch.equal(before[k], after[k]))
    assert moved
    assert all(k.startswith("progress_head.") for k in moved), moved
    with pytest.raises(ExportError, match="nothing would be trained"):
        freeze_parts(tiny_model(1), [*rest, "progress_head"])


def test_cli_init_takes_the_size_from_the_checkpoint(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    write_session(tmp_path / "a.scotti", 80, subject="a")
    base = [str(tmp_path / "a.scotti"), "--epochs", "1", "--batch", "8", "--chunk", "4"]
    first = tmp_path / "runs" / "first"
    assert main(["train", *base, "-o", str(first), "--config", json.dumps(TINY)]) == 0
    second = tmp_path / "runs" / "second"
    init = ["--init", str(first / "last.pt"), "--freeze", "cnn"]
    assert main(["train", *base, "-o", str(second), *init]) == 0
    a = torch.load(first / "last.pt", weights_only=True)
    b = torch.load(second / "last.pt", weights_only=True)
    assert b["config"] == a["config"]
    assert list(b["options"]["freeze"]) == ["cnn"]
    assert b["training_data"]["init"] == str(first / "last.pt")
    assert torch.equal(a["model"]["cnn.conv1.weight"], b["model"]["cnn.conv1.weight"])
    assert b["epoch"] == 1  # a new run, not a resume
    capsys.readouterr()
    bad = ["--config", "tiny", "-o", str(tmp_path / "r")]
    assert main(["train", *base, *init, *bad]) == 2
    assert "leave out --config" in capsys.readouterr().err
