"""A training checkpoint read back out of an exported graph, checked against it.

models/ ships ONNX graphs, not the checkpoints they came from, so a user who
wants to fine-tune the shipped model on their own recordings has no
checkpoint to start from. ``scotti train --init NAME.onnx`` takes the graph
itself; this module rebuilds the torch weights from it.

What the export changed, and how it is undone:
- the frame CNN's batch norm is folded into its projection: the projection
  keeps the folded weights and the batch norm becomes the identity (mean 0,
  variance 1 - eps, scale 1, shift 0), which computes the same in eval mode;
- the pooling weights are stored as their softmax: their logarithm has the
  same softmax;
- the attention and feed-forward matrices are stored transposed, as MatMul
  initialisers in the order the layers use them;
- the streaming-native form (export/model_streaming.py) has no pooling logits in
  the graph, only the softmax's weights of the T frames (the output token's is
  one minus their sum), and each layer's relative bias ``rel_bias[h, offset]``
  is spread into the (1, h, T+1, T+1) bias the window's tokens add: the output
  token's row, the last, holds every offset 0..T once.

Because the last point depends on how torch's exporter names and orders
things, the rebuilt model is always run beside the window graph on the same
windows and refused if any output differs by more than ``TOLERANCE``: a
checkpoint that does not compute what the graph computes is never handed to
training.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Final

import numpy as np
import torch
from scotti.export.errors import ExportError
from scotti.export.model import ModelConfigError, Scotti, ScottiConfig
from scotti.models.contract import META_CARD

TOLERANCE: Final = 1e-3  # largest |torch - graph| of any output allowed
WINDOW_SUFFIX: Final = ".window.onnx"
PER_LAYER: Final = 4  # MatMul weights per encoder layer: qkv, out, feed-forward up and down


class GraphWeightsError(ExportError):
    """A graph whose weights cannot be read back into a checkpoint (one-line message)."""


def window_graph_of(path: Path) -> Path:
    """The window graph beside a step graph (NAME.onnx -> NAME.window.onnx), or path itself."""
    if path.name.endswith(WINDOW_SUFFIX):
        return path
    window = path.with_name(path.name.removesuffix(".onnx") + WINDOW_SUFFIX)
    if not window.is_file():
        msg = f"{path}: the weights are read from its window graph, {window.name}, not found"
        raise GraphWeightsError(msg)
    return window


def _load(path: Path) -> tuple[dict[str, np.ndarray], list[np.ndarray], dict[str, Any]]:
    import onnx
    from onnx import numpy_helper

    try:
        graph = onnx.load(str(path))
    except FileNotFoundError:
        raise GraphWeightsError(f"{path}: no such file") from None
    except Exception as exc:  # onnx raises several kinds for a damaged or foreign file
        raise GraphWeightsError(
            f"{path}: not a readable ONNX graph ({type(exc).__name__})"
        ) from None
    found = {i.name: numpy_helper.to_array(i) for i in graph.graph.initializer}
    # Keyed in the order the nodes first use them: graph order is the layers' order.
    named = {n: found[n] for node in graph.graph.node for n in node.input if n in found}
    named |= found
    matmuls = [
        named[name]
        for node in graph.graph.node
        if node.op_type == "MatMul"
        for name in node.input
        if name in named and named[name].ndim == 2 and not name.startswith("model.")
    ]
    meta = {p.key: p.value for p in graph.metadata_props}
    try:
        card = json.loads(meta[META_CARD])
        config = dict(card["config"])
    except (KeyError, ValueError, TypeError):
        raise GraphWeightsError(
            f"{path}: not a SCOTTI graph (no model card with a config)"
        ) from None
    return named, matmuls, config


def has_folded_norm(state: dict[str, torch.Tensor]) -> bool:
    """Whether the frame CNN's batch norm has the statistics a graph's weights are read
    back with (mean 0, variance 1 - eps, below): weights from a graph, or fine-tuned from
    one with the statistics kept. Scale and shift may have trained; a norm that ran on
    batch statistics never ends on exactly these."""
    mean, var = state.get("cnn.norm.running_mean"), state.get("cnn.norm.running_var")
    if mean is None or var is None:
        return False
    return bool(torch.all(mean == 0)) and bool(
        torch.allclose(var.float(), torch.full_like(var.float(), 1.0 - 1e-5), rtol=0, atol=1e-7)
    )


def _state(path: Path) -> tuple[ScottiConfig, dict[str, torch.Tensor]]:
    named, matmuls, config = _load(path)
    try:
        cfg = ScottiConfig.from_dict(config)
    except ModelConfigError as exc:
        raise GraphWeightsError(f"{path}: its card's config is not usable ({exc})") from None
    fresh = Scotti(cfg)
    own = fresh.state_dict()
    state = {k: torch.from_numpy(named[f"model.{k}"].copy()) for k in own if f"model.{k}" in named}
    e, eps = cfg.embed_dim, fresh.cnn.norm.eps
    state["cnn.norm.weight"] = torch.ones(e)
    state["cnn.norm.bias"] = torch.zeros(e)
    state["cnn.norm.running_mean"] = torch.zeros(e)
    state["cnn.norm.running_var"] = torch.full((e,), 1.0 - eps)
    state["cnn.norm.num_batches_tracked"] = own["cnn.norm.num_batches_tracked"]
    pooling = (
        _streaming_pooling(named, cfg) if cfg.arch == "streaming" else _paper_pooling(named, cfg)
    )
    if pooling is None:
        raise GraphWeightsError(f"{path}: cannot find its pooling weights")
    state["pool_weights"] = torch.from_numpy(np.log(pooling).astype(np.float32))
    if len(matmuls) != PER_LAYER * cfg.layers:
        msg = f"{path}: {len(matmuls)} MatMul weights where {PER_LAYER * cfg.layers} were expected"
        raise GraphWeightsError(msg)
    layer = "streaming.layers.{}" if cfg.arch == "streaming" else "encoder.{}"
    names = ("attn.qkv", "attn.out", "mlp.0", "mlp.2")
    for i in range(cfg.layers):
        for name, array in zip(names, matmuls[PER_LAYER * i : PER_LAYER * (i + 1)], strict=True):
            state[f"{layer.format(i)}.{name}.weight"] = torch.from_numpy(array.T.copy())
    if cfg.arch == "streaming":
        t = cfg.window
        biases = [a for a in named.values() if a.shape == (1, cfg.heads, t + 1, t + 1)]
        if len(biases) != cfg.layers:
            msg = f"{path}: {len(biases)} attention biases where {cfg.layers} were expected"
            raise GraphWeightsError(msg)
        for i, bias in enumerate(biases):  # the output token's row: key T - offset
            rel = bias[0, :, t, ::-1].copy()
            state[f"streaming.layers.{i}.attn.rel_bias"] = torch.from_numpy(rel)
    missing = sorted(set(own) - set(state))
    if missing:
        raise GraphWeightsError(f"{path}: no weights found for {', '.join(missing[:4])}")
    for key, value in state.items():
        if tuple(value.shape) != tuple(own[key].shape):
            msg = f"{path}: {key} is {tuple(value.shape)}, the model's {tuple(own[key].shape)}"
            raise GraphWeightsError(msg)
    return cfg, state


def _paper_pooling(named: dict[str, np.ndarray], cfg: ScottiConfig) -> np.ndarray | None:
    """The paper form's softmax of the pooling weights, a (T+1,) initialiser."""
    pools = [
        a for n, a in named.items() if n.startswith("softmax") and a.shape == (cfg.window + 1,)
    ]
    return pools[0].astype(np.float64) if len(pools) == 1 else None


def _streaming_pooling(named: dict[str, np.ndarray], cfg: ScottiConfig) -> np.ndarray | None:
    """The streaming-native form's softmax of the pooling weights: the T frames' share is
    a (T,) initialiser of positive weights summing below 1, the output token's the rest."""
    frames = [
        a.astype(np.float64)
        for a in named.values()
        if a.shape == (cfg.window,) and a.dtype == np.float32 and (a > 0).all() and a.sum() < 1
    ]
    if len(frames) != 1:
        return None
    return np.concatenate([[1.0 - frames[0].sum()], frames[0]])


def compare(
    cfg: ScottiConfig, state: dict[str, torch.Tensor], graph: Path, frames: np.ndarray
) -> dict[str, float]:
    """Largest |torch - graph| per output on ``frames`` (B, T, H, 2W) float32 counts."""
    import onnxruntime as ort

    model = Scotti(cfg)
    model.load_state_dict(state)
    model.eval()
    with torch.no_grad():
        ours = model(torch.from_numpy(frames))
    session = ort.InferenceSession(str(graph), providers=["CPUExecutionProvider"])
    names = [o.name for o in session.get_outputs()]
    theirs = dict(zip(names, session.run(None, {"frames": frames}), strict=True))
    return {
        "pose": float(np.abs(ours.pose.numpy() - theirs["pose"]).max()),
        "action_logits": float(np.abs(ours.action_logits.numpy() - theirs["action_logits"]).max()),
        "progress": float(np.abs(ours.progress.numpy() - theirs["progress"]).max()),
    }


def random_windows(cfg: ScottiConfig, count: int = 8, seed: int = 0) -> np.ndarray:
    """Seeded windows of counts across the whole 12-bit range."""
    rng = np.random.default_rng(seed)
    shape = (count, cfg.window, *cfg.frame_shape)
    return rng.integers(0, 4096, size=shape).astype(np.float32)


def checkpoint_from_graph(path: Path | str, frames: np.ndarray | None = None) -> dict[str, Any]:
    """A checkpoint dict (config, model, rebuilt_from, parity) computing what the graph does.

    ``frames`` (B, T, H, 2W) are the windows both run on (default: seeded random
    counts); GraphWeightsError if the rebuilt model disagrees with the graph.
    """
    window = window_graph_of(Path(path))
    cfg, state = _state(window)
    diffs = compare(cfg, state, window, random_windows(cfg) if frames is None else frames)
    worst = max(diffs.values())
    if not worst <= TOLERANCE:
        msg = f"{path}: the weights read back differ from the graph by {worst:.2e} (> {TOLERANCE})"
        raise GraphWeightsError(msg)
    return {
        "config": cfg.to_dict(),
        "model": state,
        "rebuilt_from": str(path),
        "parity": diffs,
    }
