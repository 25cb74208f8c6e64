"""A torch checkpoint rebuilt from a shipped model's window graph, checked against it.

    python experiments/checkpoint_from_onnx.py models/scotti-default.window.onnx \
        -o runs/default-p1/best.pt --check data/corpus7/realistic/subject-011.ses

Why: models/ ships ONNX graphs, not the checkpoints they came from, and run
directories (runs/) are not kept between machines. Fine-tuning the shipped
model (``scotti train --init``) needs its weights as a checkpoint; this reads
them back out of the graph.

What the export changed, and how it is undone:
- the frame CNN's batch norm is folded into its projection: the projection
  keeps the folded weights and the batch norm becomes the identity (mean 0,
  variance 1 - eps, scale 1, shift 0), which computes the same in eval mode;
- the pooling weights are stored as their softmax: their logarithm has the
  same softmax;
- the attention and feed-forward matrices are stored transposed (MatMul
  initialisers in the order the layers use them).

The rebuilt model is run on windows of a real session (or random counts)
beside the graph, and the largest difference of each output is printed; a
difference above --tolerance is an error, so a checkpoint that does not
compute what the graph computes is never written.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

META_CARD = "scotti.card"


def _arrays(graph_path: Path) -> tuple[dict[str, np.ndarray], list[np.ndarray], dict[str, str]]:
    import onnx
    from onnx import numpy_helper

    model = onnx.load(str(graph_path))
    named = {i.name: numpy_helper.to_array(i) for i in model.graph.initializer}
    matmuls = []
    for node in model.graph.node:  # graph order is the order the layers run in
        if node.op_type == "MatMul":
            for name in node.input:
                if name in named and named[name].ndim == 2 and not name.startswith("model."):
                    matmuls.append(named[name])
    meta = {p.key: p.value for p in model.metadata_props}
    return named, matmuls, meta


def rebuild(graph_path: Path) -> dict:
    """The checkpoint dict (config, model) whose model computes what the graph does."""
    import torch
    from scotti.export.model import Scotti, ScottiConfig

    named, matmuls, meta = _arrays(graph_path)
    card = json.loads(meta[META_CARD])
    cfg = ScottiConfig.from_dict(card["config"])
    model = Scotti(cfg)
    state = model.state_dict()
    new: dict[str, torch.Tensor] = {}
    for key in state:
        if f"model.{key}" in named:
            new[key] = torch.from_numpy(named[f"model.{key}"].copy())
    # The folded batch norm: identity in eval mode.
    eps = model.cnn.norm.eps
    new["cnn.norm.weight"] = torch.ones(cfg.embed_dim)
    new["cnn.norm.bias"] = torch.zeros(cfg.embed_dim)
    new["cnn.norm.running_mean"] = torch.zeros(cfg.embed_dim)
    new["cnn.norm.running_var"] = torch.full((cfg.embed_dim,), 1.0 - eps)
    new["cnn.norm.num_batches_tracked"] = state["cnn.norm.num_batches_tracked"]
    softmax = [
        a for n, a in named.items() if a.shape == (cfg.window + 1,) and n.startswith("softmax")
    ]
    if len(softmax) != 1:
        raise SystemExit(f"{graph_path}: cannot find the pooling weights")
    new["pool_weights"] = torch.from_numpy(np.log(softmax[0].astype(np.float64)).astype(np.float32))
    per_layer = 4  # qkv, out, mlp.0, mlp.2
    if len(matmuls) != per_layer * cfg.layers:
        raise SystemExit(
            f"{graph_path}: {len(matmuls)} MatMul weights, expected {per_layer * cfg.layers}"
        )
    for i in range(cfg.layers):
        qkv, out, up, down = matmuls[per_layer * i : per_layer * (i + 1)]
        for name, array in (("attn.qkv", qkv), ("attn.out", out), ("mlp.0", up), ("mlp.2", down)):
            new[f"encoder.{i}.{name}.weight"] = torch.from_numpy(array.T.copy())
    missing = sorted(set(state) - set(new))
    if missing:
        raise SystemExit(f"{graph_path}: no weights found for {missing[:4]}")
    for key, value in new.items():
        if tuple(value.shape) != tuple(state[key].shape):
            raise SystemExit(f"{key}: graph {tuple(value.shape)}, model {tuple(state[key].shape)}")
    model.load_state_dict(new)
    return {"config": cfg.to_dict(), "model": model.state_dict(), "rebuilt_from": str(graph_path)}


def windows_for_check(session: Path | None, window: int, count: int = 64) -> np.ndarray:
    """(count, T, H, 2W) float32 counts: a session's windows, or random ones without it."""
    rng = np.random.default_rng(0)
    if session is None:
        return rng.integers(0, 4096, size=(count, window, 32, 44)).astype(np.float32)
    from scotti.export.data import load_session

    frames = load_session(session).frames
    starts = np.linspace(0, len(frames) - window, count).astype(int)
    return np.stack([frames[s : s + window] for s in starts]).astype(np.float32)


def compare(ckpt: dict, graph_path: Path, frames: np.ndarray) -> dict[str, float]:
    import onnxruntime as ort
    import torch
    from scotti.export.model import Scotti, ScottiConfig

    model = Scotti(ScottiConfig.from_dict(ckpt["config"]))
    model.load_state_dict(ckpt["model"])
    model.eval()
    with torch.no_grad():
        ours = model(torch.from_numpy(frames))
    session = ort.InferenceSession(str(graph_path), providers=["CPUExecutionProvider"])
    theirs = dict(
        zip(
            [o.name for o in session.get_outputs()],
            session.run(None, {"frames": frames}),
            strict=True,
        )
    )
    return {
        "pose": float(np.abs(ours.pose.numpy() - theirs["pose"]).max()),
        "action_logits": float(np.abs(ours.action_logits.numpy() - theirs["action_logits"]).max()),
        "progress": float(np.abs(ours.progress.numpy() - theirs["progress"]).max()),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("graph", type=Path, help="a window graph (NAME.window.onnx)")
    ap.add_argument("-o", "--output", type=Path, required=True)
    ap.add_argument("--check", type=Path, help="a session file whose windows both run on")
    ap.add_argument("--tolerance", type=float, default=1e-3)
    args = ap.parse_args(argv)
    from scotti.export.checkpoint import save_checkpoint

    ckpt = rebuild(args.graph)
    frames = windows_for_check(args.check, ckpt["config"]["window"])
    diffs = compare(ckpt, args.graph, frames)
    print("largest |torch - graph|: " + ", ".join(f"{k} {v:.2e}" for k, v in diffs.items()))
    worst = max(diffs.values())
    if worst > args.tolerance:
        print(f"not written: {worst:.2e} > tolerance {args.tolerance}", file=sys.stderr)
        return 1
    save_checkpoint(ckpt, args.output)
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
