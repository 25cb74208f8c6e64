"""The streaming-native encoder: causal, relative positions, a per-layer key/value cache.

The paper's encoder adds learned absolute positions to the T+1 tokens and lets every
token attend to every other, so when the window slides by one frame every token
changes and a streaming step reruns all T+1 tokens. Here (``ScottiConfig.arch ==
"streaming"``):

- no absolute positions: each layer adds a learned bias per head on the offset
  between query and key (``rel_bias[h, offset]``, offset 0..T, started as ALiBi);
- a frame token attends to itself and the T-1 frames before it (causal, sliding
  window of T); it never sees the output token;
- the output token (the class token, placed one slot after the newest frame, as
  time t is) attends to the last T frame tokens and itself.

So a frame's keys and values at every layer, and its final state, never change once
computed: a step runs the new frame's token through the layers over the cache of the
previous T-1 frames, then the output token over the same cache: 2 tokens, not T+1.
The pooling is the paper's (learned weights over the output token and the T frames'
final states, with the recency prior), read from the cache too.

What the cache holds per frame: ``2 * layers + 1`` vectors of E, in this order:
key and value of layer 0, of layer 1, ..., then the frame's final (layer-normed)
state (``kv_slots``). A frame's state after layer l depends on frames up to
``l * (T - 1)`` back, and the pooling reads the T frames' final states, so the
prediction for time t reads the last ``receptive_field`` frames: T + layers (T - 1)
(118 frames, 7.4 s at 16 Hz, for T = 40 and 2 layers; the paper form reads T).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import torch
from torch import nn

if TYPE_CHECKING:
    from scotti.export.model import ScottiConfig

NEG = -1e9  # additive mask: softmax weight exactly 0 in float32, no inf - inf NaN


def kv_slots(layers: int) -> int:
    """Vectors of E cached per frame: key and value per layer, then the final state."""
    return 2 * layers + 1


def receptive_field(window: int, layers: int) -> int:
    """Frames the prediction for time t depends on in steady streaming."""
    return window + layers * (window - 1)


def alibi_bias(heads: int, window: int) -> torch.Tensor:
    """(heads, T+1) start of the relative bias: -slope_h * offset, slopes 2^-8(h+1)/H.

    Some heads start local (slope 1/4: 10 logits down at 40 frames), some nearly
    global, as in ALiBi (Press et al.); the table is learned from there.
    """
    slopes = torch.tensor([2.0 ** (-8.0 * (h + 1) / heads) for h in range(heads)])
    return -slopes[:, None] * torch.arange(window + 1, dtype=torch.float32)[None, :]


class KvAttention(nn.Module):
    """Multi-head attention whose keys and values can come from a cache."""

    def __init__(self, cfg: ScottiConfig) -> None:
        super().__init__()
        self.heads = cfg.heads
        self.qkv = nn.Linear(cfg.embed_dim, 3 * cfg.embed_dim)
        self.out = nn.Linear(cfg.embed_dim, cfg.embed_dim)
        self.dropout = nn.Dropout(cfg.dropout)
        self.rel_bias = nn.Parameter(alibi_bias(cfg.heads, cfg.window))

    def split_heads(self, x: torch.Tensor) -> torch.Tensor:
        b, n, e = x.shape  # (B, n, E) -> (B, h, n, E/h)
        return x.view(b, n, self.heads, e // self.heads).transpose(1, 2)

    def attend(
        self, q: torch.Tensor, k: torch.Tensor, v: torch.Tensor, bias: torch.Tensor
    ) -> torch.Tensor:
        """q (B, nq, E), k and v (B, nk, E), bias (B or 1, h, nq, nk) -> (B, nq, E)."""
        b, nq, e = q.shape
        qh, kh, vh = self.split_heads(q), self.split_heads(k), self.split_heads(v)
        att = (qh @ kh.transpose(-2, -1)) * (1.0 / math.sqrt(e // self.heads)) + bias
        att = self.dropout(att.softmax(dim=-1))
        y = (att @ vh).transpose(1, 2).reshape(b, nq, e)  # (B, nq, E)
        out: torch.Tensor = self.dropout(self.out(y))
        return out


class KvLayer(nn.Module):
    """Pre-norm block as the paper form's (same parameter names), keys/values exposed."""

    def __init__(self, cfg: ScottiConfig) -> None:
        super().__init__()
        self.ln1 = nn.LayerNorm(cfg.embed_dim)
        self.attn = KvAttention(cfg)
        self.ln2 = nn.LayerNorm(cfg.embed_dim)
        self.mlp = nn.Sequential(
            nn.Linear(cfg.embed_dim, cfg.feedforward_dim),
            nn.GELU(),
            nn.Linear(cfg.feedforward_dim, cfg.embed_dim),
            nn.Dropout(cfg.dropout),
        )

    def qkv(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        q, k, v = self.attn.qkv(self.ln1(x)).split(x.shape[-1], dim=-1)
        return q, k, v

    def finish(self, x: torch.Tensor, attended: torch.Tensor) -> torch.Tensor:
        x = x + attended
        out: torch.Tensor = x + self.mlp(self.ln2(x))
        return out


def sequence_bias(
    rel_bias: torch.Tensor, frames: int, outputs: torch.Tensor, window: int
) -> torch.Tensor:
    """(h, N+K, N+K) bias over [N frame tokens, K output tokens] (the training form).

    Frame i sees frames i-T+1..i; output k, at position outputs[k], sees frames
    outputs[k]-T..outputs[k]-1 and itself; everything else is masked.
    """
    pos = torch.cat([torch.arange(frames, device=outputs.device), outputs])  # (N+K,)
    is_frame = torch.arange(pos.shape[0], device=outputs.device) < frames
    offset = pos[:, None] - pos[None, :]  # query minus key
    frame_q = is_frame[:, None]
    sees_frame = is_frame[None, :] & (offset >= 0) & (offset < window + (~frame_q).long())
    sees_frame &= (offset > 0) | frame_q  # an output token is after every frame it reads
    itself = torch.eye(pos.shape[0], dtype=torch.bool, device=outputs.device)
    allowed = sees_frame | (itself & ~frame_q)
    table = rel_bias[:, offset.clamp(0, window)]  # (h, N+K, N+K)
    return torch.where(allowed, table, torch.full_like(table, NEG))


class StreamingEncoder(nn.Module):
    """The layers, the final norm and the pooling; the CNN and heads live in Scotti."""

    def __init__(self, cfg: ScottiConfig) -> None:
        super().__init__()
        self.window = cfg.window
        self.layers = nn.ModuleList(KvLayer(cfg) for _ in range(cfg.layers))
        self.ln_final = nn.LayerNorm(cfg.embed_dim)

    def sequence(
        self, emb: torch.Tensor, outputs: torch.Tensor, token: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """emb (B, N, E) consecutive frames, output positions (K,) in T..N ->
        final states of the frames (B, N, E) and of the output tokens (B, K, E)."""
        b, n, _ = emb.shape
        x = torch.cat([emb, token.expand(b, outputs.shape[0], -1)], dim=1)  # (B, N+K, E)
        for layer in self.layers:
            assert isinstance(layer, KvLayer)
            bias = sequence_bias(layer.attn.rel_bias, n, outputs, self.window)[None]
            q, k, v = layer.qkv(x)
            x = layer.finish(x, layer.attn.attend(q, k, v, bias))
        x = self.ln_final(x)
        return x[:, :n], x[:, n:]

    def step(
        self, emb: torch.Tensor, past: torch.Tensor, valid: torch.Tensor, token: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """One new frame over the cache.

        emb (B, E) the new frame's embedding; past (B, T-1, S, E) the cache of the
        previous T-1 frames, oldest first; valid (B, T-1), 1 where a slot holds a
        frame (0 while warming up). Returns the new frame's cache row (B, S, E), the
        output token's final state (B, E) and the frames' final states (B, T, E).
        """
        t = self.window
        b = emb.shape[0]
        # Both tokens in one attention per layer (half the operators of one each: at
        # batch 1 onnxruntime's cost per operator is most of a step). Rows: the new
        # frame, the output token; keys: the T-1 past frames, the new frame, the token.
        empty = (1.0 - valid)[:, None, None, :] * NEG  # (B, 1, 1, T-1)
        padding = torch.cat([empty.expand(-1, -1, 2, -1), empty.new_zeros(b, 1, 2, 2)], dim=-1)
        x = torch.cat([emb[:, None], token.expand(b, 1, -1)], dim=1)  # (B, 2, E)
        present = []
        for i, layer in enumerate(self.layers):
            assert isinstance(layer, KvLayer)
            rel = layer.attn.rel_bias  # (h, T+1)
            # the frame sees offsets T-1..0 and not the token; the token T..1 and itself
            frame_row = torch.cat([rel[:, :t].flip(-1), torch.full_like(rel[:, :1], NEG)], -1)
            bias = torch.stack([frame_row, rel.flip(-1)], dim=1)[None] + padding  # (B, h, 2, T+1)
            q, k, v = layer.qkv(x)  # (B, 2, E) each
            keys = torch.cat([past[:, :, 2 * i], k], dim=1)  # (B, T+1, E), oldest first
            values = torch.cat([past[:, :, 2 * i + 1], v], dim=1)
            present += [k[:, 0], v[:, 0]]
            x = layer.finish(x, layer.attn.attend(q, keys, values, bias))
        final = self.ln_final(x)  # (B, 2, E): the new frame, the output token
        present.append(final[:, 0])
        frames = torch.cat([past[:, :, -1], final[:, :1]], dim=1)  # (B, T, E)
        return torch.stack(present, dim=1), final[:, 1], frames


def pool(weights: torch.Tensor, token: torch.Tensor, frames: torch.Tensor) -> torch.Tensor:
    """The paper's weighted mean: softmax(weights) over [output token, T frames oldest first].

    token (B, E), frames (B, T, E) -> (B, E).
    """
    w = weights.softmax(dim=0)
    return token * w[0] + torch.einsum("bte,t->be", frames, w[1:])


def window_positions(length: int, window: int, stride: int, device: torch.device) -> torch.Tensor:
    """Output positions of the windows of a run of ``length`` frames: T, T+s, ..."""
    return torch.arange(window, length + 1, stride, device=device)


def gather_windows(frames: torch.Tensor, outputs: torch.Tensor, window: int) -> torch.Tensor:
    """frames (B, N, E), output positions (K,) -> the frames each reads (B, K, T, E)."""
    idx = outputs[:, None] - window + torch.arange(window, device=outputs.device)[None, :]
    return frames[:, idx]
