"""Running a model over windows (chunked), and validation with the paper's metrics.

``chunked_outputs`` is the one place where windows are built from shared
frame embeddings; training and evaluation both go through it.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from scotti.export.losses import LossWeights, ScottiTargets, scotti_loss
from scotti.export.model import Scotti, ScottiOutputs
from scotti.export.windows import Targets, WindowDataset
from scotti.models import contract, metrics


def unfold_windows(emb: torch.Tensor, window: int, stride: int) -> torch.Tensor:
    """Embeddings of consecutive frames (L, E) -> windows (K, T, E), K = (L-T)//stride + 1."""
    return emb.unfold(0, window, stride).transpose(1, 2)  # (K, E, T) -> (K, T, E), a view


def chunked_outputs(
    model: Scotti, chunk_frames: Sequence[torch.Tensor], window: int, stride: int
) -> ScottiOutputs:
    """Outputs for every window of every chunk, each frame through the CNN once."""
    return chunked_outputs_pooled(model, chunk_frames, window, stride)[0]


def chunked_outputs_pooled(
    model: Scotti, chunk_frames: Sequence[torch.Tensor], window: int, stride: int
) -> tuple[ScottiOutputs, torch.Tensor]:
    """``chunked_outputs`` and the pooled vectors (B, E) the heads read."""
    lengths = [f.shape[0] for f in chunk_frames]
    emb = model.embed_frames(torch.cat(list(chunk_frames)))  # (sum L, E)
    if model.cfg.arch == "streaming":  # a chunk is a stream: its later windows get history
        runs = torch.split(emb, lengths)
        if len(set(lengths)) == 1:
            return model.forward_windows_pooled(torch.stack(runs), stride)
        outs = [model.forward_windows_pooled(r[None], stride) for r in runs]
        heads = ScottiOutputs(
            *(torch.cat(parts) for parts in zip(*(o for o, _ in outs), strict=True))
        )
        return heads, torch.cat([p for _, p in outs])
    windows = [unfold_windows(e, window, stride) for e in torch.split(emb, lengths)]
    return model.forward_embeddings_pooled(torch.cat(windows))  # (B, T, E) -> heads, pooled


def to_targets(targets: Sequence[Targets]) -> ScottiTargets:
    return ScottiTargets(
        pose=torch.from_numpy(np.concatenate([t.keypoints for t in targets])),
        action=torch.from_numpy(np.concatenate([t.action for t in targets])),
        progress=torch.from_numpy(np.concatenate([t.progress for t in targets])),
    )


# Windows per chunk in evaluation: no gradients, so long chunks cost little memory.
EVAL_CHUNK = 64


def predict(
    model: Scotti, dataset: WindowDataset, stride: int
) -> tuple[ScottiOutputs, dict[str, np.ndarray]]:
    """Outputs for every usable window at ``stride`` (phase 0), and their labels."""
    was_training = model.training
    model.eval()
    device = next(model.parameters()).device  # the model's, CPU or GPU; results come back
    outs: list[ScottiOutputs] = []
    keypoints, action, progress = [], [], []
    with torch.no_grad():
        for c in dataset.chunks(stride=stride, chunk=EVAL_CHUNK):
            frames = torch.from_numpy(dataset.frames(c).astype(np.float32)).to(device)
            out = chunked_outputs(model, [frames], dataset.window, stride)
            outs.append(ScottiOutputs(*(o.float().cpu() for o in out)))
            t = dataset.targets(c)
            keypoints.append(t.keypoints)
            action.append(t.action)
            progress.append(t.progress)
    model.train(was_training)
    if not outs:
        empty = ScottiOutputs(
            torch.zeros(0, contract.NUM_KEYPOINTS, 3),
            torch.zeros(0, contract.NUM_ACTIONS),
            torch.zeros(0),
        )
        return empty, {}
    joined = ScottiOutputs(*(torch.cat(parts) for parts in zip(*outs, strict=True)))
    labels = {
        "keypoints": np.concatenate(keypoints),
        "action": np.concatenate(action),
        "progress": np.concatenate(progress),
    }
    return joined, labels


def evaluate(
    model: Scotti, dataset: WindowDataset, stride: int, weights: LossWeights | None = None
) -> dict[str, Any]:
    """Loss and task metrics (MPJPE mm, MPJAE deg, action accuracy, progress MSE, APP)."""
    out, labels = predict(model, dataset, stride)
    if not labels:
        return {"windows": 0}
    targets = to_targets([Targets(labels["keypoints"], labels["action"], labels["progress"])])
    loss, parts = scotti_loss(out, targets, weights or LossWeights())
    pose = out.pose.numpy()
    # Windows with any labelled keypoint; the metrics leave out missing ones (NaN).
    pose_ok = np.isfinite(labels["keypoints"]).all(axis=2).any(axis=1)
    predicted_action = out.action_logits.argmax(dim=1).numpy().astype(np.int64)
    progress = out.progress.numpy()
    # Progress counts only where there is an action (the loss's mask too).
    progress_true = np.where(labels["action"] >= 0, labels["progress"], np.nan).astype(np.float64)
    return {
        "windows": int(pose.shape[0]),
        "loss": float(loss),
        "loss_pose": float(parts["pose"]),
        "loss_action": float(parts["action"]),
        "loss_progress": float(parts["progress"]),
        "mpjpe_mm": metrics.mpjpe_mm(pose, labels["keypoints"], pose_ok),
        "mpjae_deg": metrics.mpjae_deg(pose, labels["keypoints"], pose_ok),
        "action_accuracy": metrics.action_accuracy(predicted_action, labels["action"]),
        "progress_mse": metrics.progress_mse(progress, progress_true),
        "app": metrics.app(progress, progress_true),
    }
