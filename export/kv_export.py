"""The streaming-native form's step graph (a per-layer key/value cache) and its proof.

``KvStepGraph`` takes the new frame, the cache rows of the previous T-1 frames
(``past_kv`` (B, T-1, S, E): key and value of each layer and the final state, oldest
first) and which slots hold a frame (``past_valid`` (B, T-1)), and returns the heads,
the new frame's row (``present_kv`` (B, S, E)) and the pooled vector. The window graph
is the paper form's ``WindowGraph`` (same I/O): a stream started at the window's first
frame. ``prove_kv`` checks, on the hard inputs and a sequence:

- window graph == torch on the hard windows;
- step graph streamed over a sequence from an empty cache (its own rows as the cache)
  == torch's window forward over the whole sequence, every window in it;
- the same streamed steps over the sequence's first T frames == the window graph.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import torch
from scotti.export.errors import ExportError
from scotti.export.model import Scotti, ScottiConfig
from scotti.export.model_streaming import kv_slots, receptive_field
from scotti.export.parity import (
    HEAD_OUTPUTS,
    WINDOW_INPUTS,
    WINDOW_OUTPUTS,
    Arrays,
    Report,
    Tolerance,
    _compare,
    check_sane,
    hard_windows,
    run,
    session,
    stream_sequence,
    torch_window,
)
from scotti.models import contract
from scotti.models.kv_contract import (
    KV_GRAPH,
    KV_INPUT_PAST,
    KV_INPUT_VALID,
    KV_OUTPUT_PRESENT,
    KV_STEP_INPUTS,
    KV_STEP_OUTPUTS,
    META_KV_SLOTS,
    META_RECEPTIVE_FIELD,
    META_STEP_KIND,
    STEP_KIND_KV,
)
from torch import nn


class KvStepGraph(nn.Module):
    """One new frame over the key/value cache: what a streaming-native daemon runs."""

    def __init__(self, model: Scotti) -> None:
        super().__init__()
        self.model = model

    def forward(
        self, frame: torch.Tensor, past_kv: torch.Tensor, past_valid: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        emb = self.model.embed_frames(frame)  # (B, E)
        (pose, logits, progress), present, pooled = self.model.step_pooled(emb, past_kv, past_valid)
        return pose, logits, progress, present, pooled


def step_example(cfg: ScottiConfig) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Inputs to trace the step graph with: two rows, one cache half warm."""
    gen = torch.Generator().manual_seed(0)
    frame = torch.rand(2, *cfg.frame_shape, generator=gen) * float(contract.MAX_COUNT)
    past = torch.randn(2, cfg.window - 1, kv_slots(cfg.layers), cfg.embed_dim, generator=gen)
    valid = torch.ones(2, cfg.window - 1)
    valid[1, : cfg.window // 2] = 0.0
    return frame, past, valid


def kv_metadata(cfg: ScottiConfig) -> dict[str, str]:
    """What the streaming-native graphs carry beyond the contract's metadata."""
    return {
        META_STEP_KIND: STEP_KIND_KV,
        META_KV_SLOTS: str(kv_slots(cfg.layers)),
        META_RECEPTIVE_FIELD: str(receptive_field(cfg.window, cfg.layers)),
        "scotti.arch": cfg.arch,
    }


def check_kv_structure(path_step: Path, path_window: Path) -> None:
    for path, want_in, want_out in (
        (path_step, KV_STEP_INPUTS, KV_STEP_OUTPUTS),
        (path_window, WINDOW_INPUTS, WINDOW_OUTPUTS),
    ):
        try:
            onnx.checker.check_model(str(path), full_check=True)
        except Exception as exc:  # checker errors are many types and many lines
            first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
            msg = f"{path.name}: ONNX checker: {first}"
            raise ExportError(msg) from None
        proto = onnx.load(str(path), load_external_data=False)
        got_in = tuple(i.name for i in proto.graph.input)
        got_out = tuple(o.name for o in proto.graph.output)
        if got_in != want_in or got_out != want_out:
            msg = f"{path.name}: I/O {got_in} -> {got_out}, wanted {want_in} -> {want_out}"
            raise ExportError(msg)


def stream_kv(step: ort.InferenceSession, frames: np.ndarray, cfg: ScottiConfig) -> Arrays:
    """Feed (N, H, 2W) frames one at a time from an empty cache (the step's own rows);
    per-step outputs stacked over N."""
    past = np.zeros((1, cfg.window - 1, kv_slots(cfg.layers), cfg.embed_dim), np.float32)
    valid = np.zeros((1, cfg.window - 1), np.float32)
    steps: list[Arrays] = []
    for frame in frames:
        feeds = {contract.STEP_INPUT_FRAME: frame[None], KV_INPUT_PAST: past, KV_INPUT_VALID: valid}
        out = run(step, feeds)
        past = np.concatenate([past[:, 1:], out[KV_OUTPUT_PRESENT][:, None]], axis=1)
        valid = np.concatenate([valid[:, 1:], np.ones((1, 1), np.float32)], axis=1)
        steps.append(out)
    return {k: np.concatenate([s[k] for s in steps]) for k in steps[0]}


def torch_sequence(model: Scotti, frames: np.ndarray) -> Arrays:
    """Torch's window forward over one run of frames (N, ...): every window in it."""
    with torch.no_grad():
        emb = model.eval().embed_frames(torch.from_numpy(frames))  # (N, E)
        heads, pooled = model.forward_windows_pooled(emb[None], 1)
    out = {n: x.numpy() for n, x in zip(HEAD_OUTPUTS, heads, strict=True)}
    return {**out, contract.OUTPUT_POOLED: pooled.numpy()}


def prove_kv(
    model: Scotti, step_path: Path, window_path: Path, threads: int, tol: Tolerance
) -> Report:
    """All checks on a streaming-native export; the max abs differences measured."""
    cfg = model.cfg
    check_kv_structure(step_path, window_path)
    step, win = session(step_path, threads), session(window_path, threads)
    frames = np.stack(list(hard_windows(cfg).values()))  # (B, T, H, 2W)
    report: Report = {}
    got = run(win, {contract.WINDOW_INPUT_FRAMES: frames})
    check_sane(got, "window graph")
    report["window_vs_torch"] = _compare(got, torch_window(model, frames), tol, "window vs torch")

    # Long enough that later windows read frames whose history reaches past them.
    seq = stream_sequence(cfg, receptive_field(cfg.window, cfg.layers) + cfg.window)
    streamed = stream_kv(step, seq, cfg)
    check_sane(streamed, "streamed steps")
    full = {k: v[cfg.window - 1 :] for k, v in streamed.items() if k in WINDOW_OUTPUTS}
    check = "streamed kv steps vs torch window forward"
    report["stream_vs_torch"] = _compare(full, torch_sequence(model, seq), tol, check)
    first = {k: v[:1] for k, v in full.items()}
    windowed = run(win, {contract.WINDOW_INPUT_FRAMES: seq[None, : cfg.window]})
    report["stream_vs_window"] = _compare(first, windowed, tol, "streamed kv steps vs window")
    return report


__all__ = [
    "KV_GRAPH",
    "KvStepGraph",
    "kv_metadata",
    "prove_kv",
    "step_example",
    "stream_kv",
    "torch_sequence",
]
