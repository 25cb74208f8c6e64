"""The streaming-native form: torch window forward == torch incremental steps == ONNX
step graph over a sequence == ONNX window graph; its runtime; its config and training path.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("torch")
import onnx
import torch
from scotti.cli.main import main
from scotti.export.errors import ExportError
from scotti.export.evaluate import chunked_outputs
from scotti.export.kv_export import stream_kv, torch_sequence
from scotti.export.losses import ScottiTargets, scotti_loss
from scotti.export.model import ModelConfigError, Scotti, ScottiConfig
from scotti.export.model_streaming import kv_slots, receptive_field
from scotti.export.onnx_export import Checkpoint, ExportResult, export_model, load_checkpoint
from scotti.export.parity import FP32, session, stream_sequence
from scotti.export.train_args import add_arguments
from scotti.models import contract
from scotti.models.errors import ModelContractError, ModelInputError
from scotti.models.kv_contract import KV_GRAPH, META_KV_SLOTS, META_STEP_KIND, STEP_KIND_KV
from scotti.models.kv_streaming import (
    KvCache,
    KvStepRuntime,
    KvStreamingWindow,
    push_many,
)
from scotti.models.runtime import ScottiRuntime

from tests.support.export_sessions import write_session

pytestmark = pytest.mark.torch

# Torch float32 against itself (batched masks vs one token at a time): summation order only.
TORCH_ATOL = 1e-5
SMALL = ScottiConfig(
    window=6, embed_dim=16, layers=2, heads=2, conv_channels=(2, 4), head_hidden=16, dropout=0.0
)
TINY_KV = ScottiConfig(
    embed_dim=32,
    layers=2,
    heads=2,
    conv_channels=(4, 8),
    head_hidden=32,
    dropout=0.0,
    arch="streaming",
)


def spread(model: Scotti, seed: int) -> Scotti:
    """Weights wider than a fresh model's, so outputs depend on the input and positions."""
    torch.manual_seed(seed)
    with torch.no_grad():
        for p in model.parameters():
            p.add_(torch.randn_like(p) * 0.3)
    return model.eval()


def incremental(model: Scotti, emb: torch.Tensor) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """Torch steps over (B, N, E) embeddings from an empty cache: (pose, pooled) per step."""
    b, n, e = emb.shape
    t = model.cfg.window
    past = torch.zeros(b, t - 1, kv_slots(model.cfg.layers), e)
    valid = torch.zeros(b, t - 1)
    out = []
    with torch.no_grad():
        for i in range(n):
            heads, present, pooled = model.step_pooled(emb[:, i], past, valid)
            past = torch.cat([past[:, 1:], present[:, None]], dim=1)
            valid = torch.cat([valid[:, 1:], torch.ones(b, 1)], dim=1)
            out.append((heads.pose, pooled))
    return out


def test_torch_window_forward_equals_incremental_steps() -> None:
    cfg = ScottiConfig(**{**SMALL.to_dict(), "arch": "streaming"})
    model = spread(Scotti(cfg), 1)
    t = cfg.window
    n = receptive_field(t, cfg.layers) + 5  # later windows read history beyond themselves
    emb = torch.randn(3, n, cfg.embed_dim)
    with torch.no_grad():
        heads, pooled = model.forward_windows_pooled(emb, 1)
    k = n - t + 1
    steps = incremental(model, emb)
    for w in range(k):  # window w ends with frame w + T - 1
        pose, pool = steps[w + t - 1]
        assert torch.allclose(pool, pooled.view(3, k, -1)[:, w], atol=TORCH_ATOL)
        assert torch.allclose(pose, heads.pose.view(3, k, 19, 3)[:, w], atol=TORCH_ATOL)
    # forward_embeddings on T frames is a stream started at the window's first frame
    first, _ = model.forward_embeddings_pooled(emb[:, :t])
    assert torch.allclose(first.pose, steps[t - 1][0], atol=TORCH_ATOL)
    # and a frame beyond the receptive field changes nothing; one inside it does
    moved = emb.clone()
    moved[:, 0] = torch.randn(3, cfg.embed_dim)  # not a constant shift: LayerNorm hides those
    with torch.no_grad():
        late = model.forward_windows_pooled(moved, 1)[1].view(3, k, -1)
        ref = pooled.view(3, k, -1)
    reach = receptive_field(t, cfg.layers)
    assert torch.allclose(late[:, reach - t + 1 :], ref[:, reach - t + 1 :], atol=TORCH_ATOL)
    assert not torch.allclose(late[:, reach - t], ref[:, reach - t], atol=1e-3)


def test_relative_positions_make_a_shifted_stream_give_the_same_rows() -> None:
    """No absolute position: the same frames later in a stream give the same outputs
    once their history is the same (what lets cached keys and values stay valid)."""
    cfg = ScottiConfig(**{**SMALL.to_dict(), "arch": "streaming"})
    model = spread(Scotti(cfg), 2)
    emb = torch.randn(1, 30, cfg.embed_dim)
    shifted = torch.cat([torch.randn(1, 7, cfg.embed_dim), emb], dim=1)
    with torch.no_grad():
        a = model.forward_windows_pooled(emb, 1)[1]
        b = model.forward_windows_pooled(shifted, 1)[1][7:]
    reach = receptive_field(cfg.window, cfg.layers)
    assert torch.allclose(a[reach - cfg.window :], b[reach - cfg.window :], atol=TORCH_ATOL)


def test_chunked_training_path_is_the_streams_windows_and_trains() -> None:
    cfg = ScottiConfig(**{**SMALL.to_dict(), "arch": "streaming"})
    model = spread(Scotti(cfg), 3)
    chunks = [torch.rand(14, *cfg.frame_shape) * 4095, torch.rand(10, *cfg.frame_shape) * 4095]
    with torch.no_grad():
        out = chunked_outputs(model, chunks, cfg.window, 2)
        want = [torch_sequence(model, c.numpy())[contract.OUTPUT_POSE][::2] for c in chunks]
    assert out.pose.shape == (5 + 3, 19, 3)
    assert np.allclose(out.pose.numpy(), np.concatenate(want), atol=TORCH_ATOL)
    model.train()
    out = chunked_outputs(model, chunks, cfg.window, 2)
    targets = ScottiTargets(
        pose=torch.zeros(8, 19, 3),
        action=torch.zeros(8, dtype=torch.long),
        progress=torch.full((8,), 0.5),
    )
    total, _ = scotti_loss(out, targets)
    total.backward()
    rel = model.streaming.layers[0].attn.rel_bias  # type: ignore[union-attr,index]
    assert rel.grad is not None
    assert rel.grad.abs().sum() > 0


def test_config_arch_is_checked_and_the_paper_form_reads_as_before() -> None:
    with pytest.raises(ModelConfigError, match="arch"):
        ScottiConfig(arch="rnn")
    assert "arch" not in ScottiConfig().to_dict()  # paper checkpoints and cards unchanged
    kv = ScottiConfig(arch="streaming")
    assert ScottiConfig.from_dict(kv.to_dict()) == kv
    paper_keys = set(Scotti(SMALL).state_dict())
    kv_keys = set(Scotti(ScottiConfig(**{**SMALL.to_dict(), "arch": "streaming"})).state_dict())
    assert "positions" in paper_keys
    assert "positions" not in kv_keys
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    args = parser.parse_args(["x", "-o", "y", "--arch", "streaming"])
    assert args.arch == "streaming"


def test_kv_cache_is_a_ring_in_order_with_valid_slots() -> None:
    cache = KvCache(size=3, slots=2, dim=1)
    assert cache.valid().tolist() == [0, 0, 0]
    for i in range(1, 5):
        cache.push(np.full((2, 1), i))
    assert cache.past()[:, 0, 0].tolist() == [2, 3, 4]
    assert cache.valid().tolist() == [1, 1, 1]
    with pytest.raises(ModelInputError, match="cache row"):
        cache.push(np.zeros((3, 1)))
    cache.reset()
    assert cache.valid().tolist() == [0, 0, 0]


@pytest.fixture(scope="module")
def kv_export(tmp_path_factory: pytest.TempPathFactory) -> tuple[Scotti, ExportResult]:
    model = spread(Scotti(TINY_KV), 4)
    out = tmp_path_factory.mktemp("kv") / "kv.onnx"
    torch.save({"config": TINY_KV.to_dict(), "model": model.state_dict()}, out.with_suffix(".pt"))
    return model, export_model(Checkpoint(model=model), out)


def test_export_proves_step_and_window_graphs_within_fp32_tolerance(
    kv_export: tuple[Scotti, ExportResult],
) -> None:
    model, result = kv_export
    assert set(result.parity) == {"window_vs_torch", "stream_vs_torch", "stream_vs_window"}
    for diffs in result.parity.values():
        assert set(diffs) >= {contract.OUTPUT_POSE, contract.OUTPUT_POOLED}
        assert max(diffs.values()) <= FP32.atol
    # The proof itself: streamed ONNX steps against torch's incremental steps too.
    seq = stream_sequence(TINY_KV, 60)
    streamed = stream_kv(session(result.paths.step), seq, TINY_KV)
    with torch.no_grad():
        emb = model.embed_frames(torch.from_numpy(seq))[None]
    steps = incremental(model, emb)
    for i in range(TINY_KV.window - 1, 60):
        assert np.allclose(streamed[contract.OUTPUT_POSE][i], steps[i][0][0], atol=FP32.atol)


def test_metadata_says_which_step_graph_and_old_runtimes_refuse_it(
    kv_export: tuple[Scotti, ExportResult],
) -> None:
    _, result = kv_export
    meta = {p.key: p.value for p in onnx.load(str(result.paths.step)).metadata_props}
    assert meta[contract.META_GRAPH] == KV_GRAPH
    assert meta[META_STEP_KIND] == STEP_KIND_KV
    assert meta[META_KV_SLOTS] == str(kv_slots(TINY_KV.layers))
    with pytest.raises(ModelContractError, match="step_kv"):
        ScottiRuntime(result.paths.step)
    window = ScottiRuntime(result.paths.window)  # the paper form's window contract
    assert window.graph == "window"
    with pytest.raises(ModelContractError, match="key/value"):
        KvStepRuntime(result.paths.window)


def test_runtime_streams_as_the_window_graph_and_batches_as_single_pushes(
    kv_export: tuple[Scotti, ExportResult],
) -> None:
    model, result = kv_export
    runtime = KvStepRuntime(result.paths.step)
    seq = stream_sequence(TINY_KV, 90)
    single = KvStreamingWindow(runtime)
    outs = [single.push(f) for f in seq]
    assert all(o is None for o in outs[: TINY_KV.window - 1])
    want = torch_sequence(model, seq)[contract.OUTPUT_POSE]
    got = np.stack([o.pose for o in outs[TINY_KV.window - 1 :] if o is not None])
    assert np.allclose(got, want, atol=FP32.atol)
    many = [KvStreamingWindow(runtime) for _ in range(3)]
    rows = [push_many(many, [f, f, f]) for f in seq]
    assert all(r[2] is not None for r in rows[TINY_KV.window - 1 :])
    last = rows[-1][1]
    assert last is not None
    assert outs[-1] is not None
    assert np.allclose(last.pose, outs[-1].pose, atol=FP32.atol)
    window = ScottiRuntime(result.paths.window).run_windows(seq[None, : TINY_KV.window])
    assert outs[TINY_KV.window - 1] is not None
    assert np.allclose(window.pose[0], outs[TINY_KV.window - 1].pose, atol=FP32.atol)
    with pytest.raises(ModelInputError, match="frame must be"):
        single.push(np.zeros((3, 3), np.float32))
    single.reset()
    assert single.warming
    assert single.past().sum() == 0


def test_checkpoint_round_trip_and_int8_is_refused(
    kv_export: tuple[Scotti, ExportResult], tmp_path: Path
) -> None:
    _, result = kv_export
    ckpt = load_checkpoint(result.paths.step.with_suffix(".pt"))
    assert ckpt.model.cfg.arch == "streaming"
    with pytest.raises(ExportError, match="int8"):
        export_model(ckpt, tmp_path / "x.onnx", int8=True)


def test_cli_trains_the_streaming_form_refuses_a_mixed_resume_and_exports(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    torch.set_num_threads(1)
    sessions = tmp_path / "sessions"
    sessions.mkdir()
    write_session(sessions / "a.scotti", 110, subject="a")
    write_session(sessions / "b.scotti", 60, subject="b")
    run = tmp_path / "run"
    config = SMALL.to_dict() | {"layers": 1}
    common = [str(sessions), "-o", str(run), "--config", json.dumps(config), "--no-progress"]
    common += ["--batch", "8", "--chunk", "4", "--stride", "2", "--val-subjects", "b"]
    common += ["--test-fraction", "0"]
    assert main(["train", *common, "--arch", "streaming", "--epochs", "1"]) == 0
    ckpt = torch.load(run / "last.pt", weights_only=True)
    assert ckpt["config"]["arch"] == "streaming"
    assert np.isfinite(ckpt["metrics"]["val"]["mpjpe_mm"])
    capsys.readouterr()
    assert main(["train", *common, "--arch", "paper", "--epochs", "2", "--resume"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "streaming form" in err[0]
    out = tmp_path / "kv.onnx"
    assert main(["export", str(run / "last.pt"), "-o", str(out)]) == 0
    meta = {p.key: p.value for p in onnx.load(str(out)).metadata_props}
    assert meta[contract.META_GRAPH] == KV_GRAPH
