"""A checkpoint read back out of an exported graph (export/graph_weights.py), and
``scotti train --init NAME.onnx`` starting from it."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("torch")
import torch
from scotti.cli.main import main
from scotti.export import graph_weights
from scotti.export.graph_weights import GraphWeightsError, checkpoint_from_graph
from scotti.export.model import Scotti, ScottiConfig

from tests.support.export_sessions import write_session
from tests.support.fixtures_models import TINY_CHECKPOINT, TINY_STEP, TINY_WINDOW

pytestmark = pytest.mark.torch


def _outputs(state: dict[str, torch.Tensor], cfg: ScottiConfig, frames: np.ndarray) -> list:
    model = Scotti(cfg)
    model.load_state_dict(state)
    model.eval()
    with torch.no_grad():
        return [t.numpy() for t in model(torch.from_numpy(frames))]


@pytest.mark.parametrize("graph", [TINY_STEP, TINY_WINDOW], ids=["step", "window"])
def test_the_rebuilt_model_computes_what_the_exported_one_did(graph: Path) -> None:
    original = torch.load(TINY_CHECKPOINT, weights_only=True)
    rebuilt = checkpoint_from_graph(graph)
    assert rebuilt["config"] == original["config"]
    cfg = ScottiConfig.from_dict(original["config"])
    # Other windows than the parity check's: real-looking low counts, not the full range.
    frames = np.random.default_rng(7).integers(0, 600, (5, cfg.window, *cfg.frame_shape))
    frames = frames.astype(np.float32)
    for ours, theirs in zip(
        _outputs(rebuilt["model"], cfg, frames),
        _outputs(original["model"], cfg, frames),
        strict=True,
    ):
        np.testing.assert_allclose(ours, theirs, atol=1e-4)
    # Weights that are stored as they are come back bit for bit.
    for name in ("cnn.conv1.weight", "encoder.0.ln1.weight", "progress_head.3.bias"):
        assert torch.equal(rebuilt["model"][name], original["model"][name]), name
    assert max(rebuilt["parity"].values()) < 1e-4


def test_a_streaming_native_export_reads_back_with_its_relative_biases(tmp_path: Path) -> None:
    """The streaming form (the shipped default's) keeps no pooling logits and spreads
    each layer's rel_bias into a bias matrix; both come back, and so does the model."""
    from scotti.export.onnx_export import Checkpoint, export_model

    from tests.test_export_streaming_native import TINY_KV, spread

    original = spread(Scotti(TINY_KV), 5)
    out = tmp_path / "kv.onnx"
    export_model(Checkpoint(model=original), out)
    rebuilt = checkpoint_from_graph(out)
    assert rebuilt["config"]["arch"] == "streaming"
    own = original.state_dict()
    for i in range(TINY_KV.layers):
        name = f"streaming.layers.{i}.attn.rel_bias"
        np.testing.assert_allclose(rebuilt["model"][name], own[name], atol=1e-6, err_msg=name)
    # Logits come back up to a constant: their softmax is what the model computes.
    np.testing.assert_allclose(
        rebuilt["model"]["pool_weights"].softmax(0), own["pool_weights"].softmax(0), atol=1e-6
    )
    frames = np.random.default_rng(8).integers(0, 600, (3, TINY_KV.window, *TINY_KV.frame_shape))
    frames = frames.astype(np.float32)
    for ours, theirs in zip(
        _outputs(rebuilt["model"], TINY_KV, frames),
        _outputs(own, TINY_KV, frames),
        strict=True,
    ):
        np.testing.assert_allclose(ours, theirs, atol=1e-4)


def test_a_step_graph_without_its_window_graph_is_refused(tmp_path: Path) -> None:
    alone = tmp_path / "scotti-tiny.onnx"
    shutil.copy(TINY_STEP, alone)
    with pytest.raises(GraphWeightsError, match=r"scotti-tiny\.window\.onnx, not found"):
        checkpoint_from_graph(alone)


def test_a_file_that_is_no_graph_is_refused(tmp_path: Path) -> None:
    bad = tmp_path / "x.window.onnx"
    bad.write_bytes(b"\x00 not a graph at all")
    with pytest.raises(GraphWeightsError, match="not a readable ONNX graph"):
        checkpoint_from_graph(bad)


def test_weights_that_do_not_reproduce_the_graph_are_refused(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The parity check is what makes the exporter's naming safe to rely on: a misread
    weight (here: two layers' roles swapped by a wrong order) never reaches training."""
    read = graph_weights._state

    def misread(path: Path) -> tuple[ScottiConfig, dict[str, torch.Tensor]]:
        cfg, state = read(path)
        state["encoder.0.mlp.0.weight"] = state["encoder.0.mlp.0.weight"].flip(0)
        return cfg, state

    monkeypatch.setattr(graph_weights, "_state", misread)
    with pytest.raises(GraphWeightsError, match="differ from the graph"):
        checkpoint_from_graph(TINY_WINDOW)


def test_train_init_takes_a_graph(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    write_session(tmp_path / "a.scotti", 120, subject="a")
    base = [str(tmp_path / "a.scotti"), "--epochs", "1", "--batch", "8", "--chunk", "4"]
    run = tmp_path / "run"
    init = ["--init", str(TINY_STEP), "--freeze", "cnn", "encoder", "pose_head", "action_head"]
    assert main(["train", *base, "-o", str(run), *init, "--loss-weights", "0,0,1"]) == 0
    ckpt = torch.load(run / "last.pt", weights_only=True)
    original = torch.load(TINY_CHECKPOINT, weights_only=True)
    assert ckpt["training_data"]["init"] == str(TINY_STEP)
    assert torch.equal(
        ckpt["model"]["action_head.3.weight"], original["model"]["action_head.3.weight"]
    )
    assert not torch.equal(
        ckpt["model"]["progress_head.3.weight"], original["model"]["progress_head.3.weight"]
    )
    capsys.readouterr()
    assert (
        main(["train", *base, "-o", str(tmp_path / "r2"), "--init", str(tmp_path / "no.onnx")]) == 2
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "no.window.onnx, not found" in err[0]


def test_a_fine_tune_of_a_graph_keeps_its_norm_statistics(tmp_path: Path) -> None:
    """The graph folded its batch norm away (identity statistics): a fine-tune runs it on
    them, as inference does, unless asked to normalise by batches."""
    write_session(tmp_path / "a.scotti", 120, subject="a")
    base = [str(tmp_path / "a.scotti"), "--epochs", "1", "--batch", "8", "--chunk", "4"]
    folded = checkpoint_from_graph(TINY_STEP)["model"]
    stats = ("cnn.norm.running_mean", "cnn.norm.running_var")
    runs = {}
    for name, extra in (("default", []), ("batch", ["--norm-statistics", "batch"])):
        run = tmp_path / name
        assert main(["train", *base, "-o", str(run), "--init", str(TINY_STEP), *extra]) == 0
        runs[name] = torch.load(run / "last.pt", weights_only=True)
    kept = runs["default"]
    assert kept["options"]["norm_statistics"] == "kept"
    for key in stats:
        assert torch.equal(kept["model"][key], folded[key]), key
    assert not torch.equal(kept["model"]["cnn.norm.weight"], folded["cnn.norm.weight"])  # trains
    assert runs["batch"]["options"]["norm_statistics"] == "batch"
    assert not torch.equal(runs["batch"]["model"][stats[0]], folded[stats[0]])
    # Resumed without the option, a run goes on as it began.
    again = ["train", *base, "-o", str(tmp_path / "default"), "--resume", "--epochs", "2"]
    assert main(again) == 0
    resumed = torch.load(tmp_path / "default" / "last.pt", weights_only=True)
    assert resumed["options"]["norm_statistics"] == "kept"
    assert torch.equal(resumed["model"][stats[0]], folded[stats[0]])


def test_weights_with_a_graphs_norm_are_told_from_trained_ones(tmp_path: Path) -> None:
    """--norm-statistics' default reads the weights, not the file name: a checkpoint
    saved from a graph's weights keeps them too; one trained on batches does not."""
    from scotti.export.graph_weights import has_folded_norm

    folded = checkpoint_from_graph(TINY_STEP)
    assert has_folded_norm(folded["model"])
    trained = torch.load(TINY_CHECKPOINT, weights_only=True)["model"]
    assert not has_folded_norm(trained)
    assert not has_folded_norm({})  # no batch norm at all
    saved = tmp_path / "from-graph.pt"
    torch.save({"config": folded["config"], "model": folded["model"]}, saved)
    write_session(tmp_path / "a.scotti", 120, subject="a")
    base = [str(tmp_path / "a.scotti"), "--epochs", "1", "--batch", "8", "--chunk", "4"]
    assert main(["train", *base, "-o", str(tmp_path / "r"), "--init", str(saved)]) == 0
    ckpt = torch.load(tmp_path / "r" / "last.pt", weights_only=True)
    assert ckpt["options"]["norm_statistics"] == "kept"
    assert has_folded_norm(ckpt["model"])  # a fine-tune so kept reads as one again
