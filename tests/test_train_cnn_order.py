"""FrameCNN takes ReLU after the max pool: the same function as the paper's ReLU then pool.

Checked against a copy of the paper's order with the same weights: torch outputs and
gradients, the committed tiny checkpoint, and ONNX graphs exported from both orders.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("torch")
import onnx
import torch
import torch.nn.functional as F
from scotti.export.model import FrameCNN, Scotti, ScottiConfig, normalise
from scotti.export.onnx_export import WindowGraph, export_graph, load_checkpoint
from scotti.export.parity import WINDOW_INPUTS, WINDOW_OUTPUTS, hard_windows, run, session
from scotti.models import contract

from tests.support.fixtures_models import TINY_CHECKPOINT

pytestmark = pytest.mark.torch

SMALL = ScottiConfig(window=6, embed_dim=16, layers=1, heads=2, head_hidden=16, dropout=0.0)
SHAPE = (contract.FRAME_ROWS, 2 * contract.FRAME_COLS)


class PaperOrderCNN(FrameCNN):
    """The CNN as the paper draws it (and as it was written before): ReLU, then pool."""

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        x = normalise(frames).unsqueeze(1)
        x = F.max_pool2d(F.relu(self.conv1(x)), 2)
        x = F.max_pool2d(F.relu(self.conv2(x)), 2)
        emb: torch.Tensor = self.norm(self.proj(x.flatten(1)))
        return emb


def paper_order(model: Scotti) -> Scotti:
    """A copy of ``model`` whose CNN runs in the paper's order, with the same weights."""
    other = Scotti(model.cfg)
    other.load_state_dict(model.state_dict())
    cnn = PaperOrderCNN(model.cfg)
    cnn.load_state_dict(model.cnn.state_dict())
    other.cnn = cnn
    return other


def sparse_frames(n: int, seed: int) -> torch.Tensor:
    """Insole-like frames: most taxels 0 (conv outputs of both signs), some pressed hard."""
    g = torch.Generator().manual_seed(seed)
    h, w2 = contract.FRAME_ROWS, 2 * contract.FRAME_COLS
    counts = torch.rand(n, h, w2, generator=g) * contract.MAX_COUNT
    return counts * (torch.rand(n, h, w2, generator=g) > 0.6)


def test_outputs_and_gradients_equal_the_paper_order() -> None:
    torch.manual_seed(3)
    new = FrameCNN(SMALL)
    old = PaperOrderCNN(SMALL)
    old.load_state_dict(new.state_dict())
    frames = sparse_frames(64, seed=1)
    out_new, out_old = new(frames), old(frames)
    assert torch.equal(out_new, out_old)
    target = torch.randn(out_new.shape, generator=torch.Generator().manual_seed(2))
    ((out_new - target) ** 2).sum().backward()
    ((out_old - target) ** 2).sum().backward()
    for (name, p_new), p_old in zip(new.named_parameters(), old.parameters(), strict=True):
        assert p_new.grad is not None
        assert p_old.grad is not None
        assert p_new.grad.abs().max() > 0, name  # the comparison is not of zeros
        assert torch.equal(p_new.grad, p_old.grad), name  # the same arithmetic, reordered


def test_the_committed_tiny_checkpoint_gives_the_same_outputs() -> None:
    model = load_checkpoint(TINY_CHECKPOINT).model.eval()
    old = paper_order(model).eval()
    frames = sparse_frames(2 * model.cfg.window, seed=4).view(2, model.cfg.window, *SHAPE)
    with torch.no_grad():
        for a, b in zip(model(frames), old(frames), strict=True):
            assert torch.equal(a, b)


def test_graphs_exported_from_both_orders_give_the_same_outputs(tmp_path: Path) -> None:
    torch.manual_seed(5)
    model = Scotti(SMALL)
    # Batch-norm statistics away from (0, 1), so the comparison sees a trained-like map.
    model.cnn.norm.running_mean.normal_(0.0, 0.5)
    model.cnn.norm.running_var.uniform_(0.5, 2.0)
    old = paper_order(model)
    example = (sparse_frames(2 * SMALL.window, seed=6).view(2, SMALL.window, *SHAPE),)
    paths = {"new": tmp_path / "new.onnx", "old": tmp_path / "old.onnx"}
    for name, m in (("new", model), ("old", old)):
        export_graph(WindowGraph(m), example, paths[name], WINDOW_INPUTS, WINDOW_OUTPUTS)
    ops = {name: [n.op_type for n in onnx.load(str(p)).graph.node] for name, p in paths.items()}
    assert ops["new"] != ops["old"]  # the two graphs really differ in their order
    windows = {k: v[None] for k, v in hard_windows(SMALL).items()}  # (1, T, H, 2W) each
    windows["sparse"] = (
        sparse_frames(3 * SMALL.window, seed=7).view(3, SMALL.window, *SHAPE).numpy()
    )
    new_sess, old_sess = session(paths["new"]), session(paths["old"])
    for case, frames in windows.items():
        got = run(new_sess, {WINDOW_INPUTS[0]: frames})
        want = run(old_sess, {WINDOW_INPUTS[0]: frames})
        for output in WINDOW_OUTPUTS:
            np.testing.assert_allclose(
                got[output], want[output], rtol=0, atol=1e-6, err_msg=f"{case} {output}"
            )
