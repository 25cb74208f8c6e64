"""SCOTTI: tactile frames in, 3D pose, action and progress out.

Han et al., "Shared Representation for 3D Pose Estimation, Action
Classification, and Progress Prediction from Tactile Signals". Each of the T
frames (left and right insole side by side, H x 2W) goes through a small CNN
and is projected to E; a learnable class token goes in front, learnable
positions are added, a transformer encoder mixes the T+1 tokens, a learned
softmax-weighted mean pools them, and three MLP heads read the pooled vector.
Frames t-T..t-1 predict time t. Choices and departures: export/MODEL.md.

The per-frame CNN (``embed_frames``) is separable from the rest
(``forward_embeddings``) so the daemon embeds each frame once and keeps the
last T-1 embeddings as a cache, like an LLM's past keys and values.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any, NamedTuple

import torch
import torch.nn.functional as F
from scotti.export import model_streaming as ms
from scotti.models import contract
from torch import nn

ARCHES = ("paper", "streaming")


class ModelConfigError(ValueError):
    """A ScottiConfig that cannot describe a working model."""


@dataclass(frozen=True)
class ScottiConfig:
    """Everything that fixes the shape of a SCOTTI model (paper: T=40, E=512)."""

    window: int = contract.WINDOW  # T, frames per window
    embed_dim: int = 512  # E, width of a frame embedding and of the transformer
    rows: int = contract.FRAME_ROWS  # H, taxel rows per insole
    cols: int = contract.FRAME_COLS  # W, taxel columns per insole (input is 2W wide)
    conv_channels: tuple[int, int] = (16, 32)  # output channels of the two conv layers
    layers: int = 4  # transformer encoder layers
    heads: int = 8  # attention heads
    ff_dim: int = 0  # feed-forward width; 0 means 4 * E
    dropout: float = 0.1
    head_hidden: int = 256  # hidden width of each MLP head
    # "paper": learned absolute positions, full attention (a step reruns T+1 tokens);
    # "streaming": relative positions, causal, a key/value cache (export/model_streaming.py)
    arch: str = "paper"

    def __post_init__(self) -> None:
        # JSON round trips turn tuples into lists; keep the frozen value hashable.
        object.__setattr__(self, "conv_channels", tuple(self.conv_channels))
        problems = []
        for name in ("window", "embed_dim", "rows", "cols", "layers", "heads", "head_hidden"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                problems.append(f"{name} must be a positive integer, got {value!r}")
        if len(self.conv_channels) != 2 or not all(
            isinstance(c, int) and c >= 1 for c in self.conv_channels
        ):
            problems.append(f"conv_channels must be two positive integers: {self.conv_channels}")
        if not isinstance(self.ff_dim, int) or self.ff_dim < 0:
            problems.append(f"ff_dim must be >= 0 (0 means 4 * embed_dim), got {self.ff_dim!r}")
        if self.arch not in ARCHES:
            problems.append(f"arch must be one of {', '.join(ARCHES)}, got {self.arch!r}")
        if not 0.0 <= float(self.dropout) < 1.0:
            problems.append(f"dropout must be in [0, 1), got {self.dropout!r}")
        if not problems and self.embed_dim % self.heads:
            problems.append(f"embed_dim {self.embed_dim} is not divisible by heads {self.heads}")
        if not problems and (self.rows < 4 or self.cols < 2):
            problems.append(f"a {self.rows}x{self.cols} frame is too small for two 2x2 poolings")
        if problems:
            raise ModelConfigError("; ".join(problems))

    @property
    def feedforward_dim(self) -> int:
        return self.ff_dim or 4 * self.embed_dim

    @property
    def frame_shape(self) -> tuple[int, int]:
        """(H, 2W): one model input frame, left foot then right foot."""
        return (self.rows, 2 * self.cols)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["conv_channels"] = list(self.conv_channels)
        if self.arch == "paper":  # the paper form's configs read as they always have
            del d["arch"]
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ScottiConfig:
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ModelConfigError(f"unknown config keys: {', '.join(unknown)}")
        try:
            return cls(**d)
        except TypeError as exc:
            raise ModelConfigError(str(exc)) from None


class ScottiOutputs(NamedTuple):
    pose: torch.Tensor  # (B, 19, 3) metres, pose frame
    action_logits: torch.Tensor  # (B, NUM_ACTIONS)
    progress: torch.Tensor  # (B,) in [0, 1]


def normalise(counts: torch.Tensor) -> torch.Tensor:
    """Raw taxel counts -> [0, 1], the same in training and inside the ONNX graph.

    Counts are clamped to the protocol's range (a corrupt value cannot blow up
    the network) and compressed with log1p: piezoresistive taxels span a wide
    dynamic range, and light contact (toes, heel strike) should not vanish
    next to full body weight on the forefoot.
    """
    x = counts.clamp(0.0, float(contract.MAX_COUNT))
    return torch.log1p(x) / math.log1p(contract.MAX_COUNT)


class FrameCNN(nn.Module):
    """One tactile frame -> one embedding: two conv layers, each 2x2 max pool + ReLU
    (the paper's ReLU + pool, the same function), a linear projection and a batch
    norm over the embedding.

    Why the batch norm: a frame is mostly the foot's static pattern; what moves
    from frame to frame (the centre of pressure, the share of each foot) is a
    few per cent of it, and without per-feature normalisation that signal is
    too small for pose and progress to be learned in a CPU-sized budget (on
    our corpus progress stayed at the constant predictor's error). At
    inference it is a fixed per-feature affine map, so each frame is still
    embedded on its own and the streaming cache stays exact.
    """

    def __init__(self, cfg: ScottiConfig) -> None:
        super().__init__()
        c1, c2 = cfg.conv_channels
        self.conv1 = nn.Conv2d(1, c1, kernel_size=3, padding=1)
        self.conv2 = nn.Conv2d(c1, c2, kernel_size=3, padding=1)
        h, w2 = cfg.rows // 4, (2 * cfg.cols) // 4  # two 2x2 poolings (floor)
        self.proj = nn.Linear(c2 * h * w2, cfg.embed_dim)
        self.norm = nn.BatchNorm1d(cfg.embed_dim)

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        x = normalise(frames).unsqueeze(1)  # (N, 1, H, 2W)
        # ReLU after the pool, not before: ReLU is monotone, so relu(maxpool(x)) equals
        # maxpool(relu(x)) exactly (values and gradients), and after the pool it touches
        # a quarter of the elements, forward and backward: the CNN, and its ReLUs
        # (~20 % of a profiled chunked step), are most of a CPU training step.
        x = F.relu(F.max_pool2d(self.conv1(x), 2))  # (N, c1, H/2, W)
        x = F.relu(F.max_pool2d(self.conv2(x), 2))  # (N, c2, H/4, W/2)
        emb: torch.Tensor = self.norm(self.proj(x.flatten(1)))  # (N, E)
        return emb


class SelfAttention(nn.Module):
    """Multi-head self-attention over all T+1 tokens (no mask: the window is the past)."""

    def __init__(self, cfg: ScottiConfig) -> None:
        super().__init__()
        self.heads = cfg.heads
        self.qkv = nn.Linear(cfg.embed_dim, 3 * cfg.embed_dim)
        self.out = nn.Linear(cfg.embed_dim, cfg.embed_dim)
        self.dropout = nn.Dropout(cfg.dropout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b, n, e = x.shape  # (B, T+1, E)
        q, k, v = self.qkv(x).split(e, dim=2)  # 3 x (B, T+1, E)
        q, k, v = (t.view(b, n, self.heads, e // self.heads).transpose(1, 2) for t in (q, k, v))
        att = (q @ k.transpose(-2, -1)) * (1.0 / math.sqrt(e // self.heads))  # (B, h, T+1, T+1)
        att = self.dropout(att.softmax(dim=-1))
        y = (att @ v).transpose(1, 2).reshape(b, n, e)  # (B, T+1, E)
        out: torch.Tensor = self.dropout(self.out(y))  # (B, T+1, E)
        return out


class EncoderLayer(nn.Module):
    """Pre-norm transformer encoder layer: x + attn(ln(x)), then x + mlp(ln(x))."""

    def __init__(self, cfg: ScottiConfig) -> None:
        super().__init__()
        self.ln1 = nn.LayerNorm(cfg.embed_dim)
        self.attn = SelfAttention(cfg)
        self.ln2 = nn.LayerNorm(cfg.embed_dim)
        self.mlp = nn.Sequential(
            nn.Linear(cfg.embed_dim, cfg.feedforward_dim),
            nn.GELU(),
            nn.Linear(cfg.feedforward_dim, cfg.embed_dim),
            nn.Dropout(cfg.dropout),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = x + self.attn(self.ln1(x))  # (B, T+1, E)
        out: torch.Tensor = x + self.mlp(self.ln2(x))  # (B, T+1, E)
        return out


def mlp_head(cfg: ScottiConfig, out_features: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Linear(cfg.embed_dim, cfg.head_hidden),
        nn.GELU(),
        nn.Dropout(cfg.dropout),
        nn.Linear(cfg.head_hidden, out_features),
    )


class Scotti(nn.Module):
    def __init__(self, cfg: ScottiConfig) -> None:
        super().__init__()
        self.cfg = cfg
        e, t = cfg.embed_dim, cfg.window
        self.cnn = FrameCNN(cfg)
        self.class_token = nn.Parameter(torch.zeros(1, 1, e))
        self.dropout = nn.Dropout(cfg.dropout)
        self.streaming: ms.StreamingEncoder | None = None
        if cfg.arch == "streaming":
            self.streaming = ms.StreamingEncoder(cfg)
        else:
            self.positions = nn.Parameter(torch.zeros(1, t + 1, e))
            self.encoder = nn.ModuleList(EncoderLayer(cfg) for _ in range(cfg.layers))
            self.ln_final = nn.LayerNorm(e)
        self.pool_weights = nn.Parameter(recency_prior(t))
        self.pose_head = mlp_head(cfg, contract.NUM_KEYPOINTS * 3)
        self.action_head = mlp_head(cfg, contract.NUM_ACTIONS)
        self.progress_head = mlp_head(cfg, 1)
        self.apply(_init_weights)
        nn.init.normal_(self.class_token, std=0.02)
        if self.streaming is None:
            nn.init.normal_(self.positions, std=0.02)

    def embed_frames(self, frames: torch.Tensor) -> torch.Tensor:
        """Raw counts (N, H, 2W) -> frame embeddings (N, E); each frame on its own."""
        emb: torch.Tensor = self.cnn(frames)  # (N, E)
        return emb

    def forward_embeddings(self, emb: torch.Tensor) -> ScottiOutputs:
        """The T frame embeddings of a window (B, T, E), oldest first -> the three heads."""
        return self.forward_embeddings_pooled(emb)[0]

    def forward_embeddings_pooled(self, emb: torch.Tensor) -> tuple[ScottiOutputs, torch.Tensor]:
        """``forward_embeddings`` plus the pooled vector (B, E) the heads read: the
        exported graphs publish it, so the runtime can tell an unfamiliar window."""
        b = emb.shape[0]
        if self.streaming is not None:  # a stream started at the window's first frame
            return self.forward_windows_pooled(emb, 1)
        cls = self.class_token.expand(b, -1, -1)  # (B, 1, E)
        x = torch.cat([cls, emb], dim=1) + self.positions  # (B, T+1, E)
        x = self.dropout(x)
        for layer in self.encoder:
            x = layer(x)  # (B, T+1, E)
        x = self.ln_final(x)
        w = self.pool_weights.softmax(dim=0)  # (T+1,), sums to 1
        pooled = torch.einsum("bte,t->be", x, w)  # (B, E), weighted mean over tokens
        return self.heads(pooled), pooled

    def heads(self, pooled: torch.Tensor) -> ScottiOutputs:
        """The three heads on the pooled vector (B, E)."""
        pose = self.pose_head(pooled).view(-1, contract.NUM_KEYPOINTS, 3)  # (B, 19, 3)
        action_logits = self.action_head(pooled)  # (B, NUM_ACTIONS)
        progress = torch.sigmoid(self.progress_head(pooled)).squeeze(-1)  # (B,)
        return ScottiOutputs(pose, action_logits, progress)

    def forward_windows_pooled(
        self, emb: torch.Tensor, stride: int
    ) -> tuple[ScottiOutputs, torch.Tensor]:
        """Streaming form: a run of consecutive frames (B, N, E), N >= T -> the heads for
        every window in it (at starts 0, stride, ...; B * K rows, run by run), each
        frame with the history the run gives it, as a stream started at its first frame.
        """
        enc = self._encoder()
        t = self.cfg.window
        outputs = ms.window_positions(emb.shape[1], t, stride, emb.device)  # (K,)
        frames, tokens = enc.sequence(self.dropout(emb), outputs, self.class_token)
        windows = ms.gather_windows(frames, outputs, t)  # (B, K, T, E)
        e = emb.shape[-1]
        pooled = ms.pool(self.pool_weights, tokens.reshape(-1, e), windows.reshape(-1, t, e))
        return self.heads(pooled), pooled

    def step_pooled(
        self, emb: torch.Tensor, past: torch.Tensor, valid: torch.Tensor
    ) -> tuple[ScottiOutputs, torch.Tensor, torch.Tensor]:
        """Streaming form, one new frame's embedding (B, E) over the cache (B, T-1, S, E)
        with its valid slots (B, T-1) -> heads, the new cache row (B, S, E), pooled."""
        present, token, frames = self._encoder().step(emb, past, valid, self.class_token)
        pooled = ms.pool(self.pool_weights, token, frames)
        return self.heads(pooled), present, pooled

    def _encoder(self) -> ms.StreamingEncoder:
        if self.streaming is None:
            msg = "this model is the paper form; streaming steps need arch='streaming'"
            raise ModelConfigError(msg)
        return self.streaming

    def forward(self, frames: torch.Tensor) -> ScottiOutputs:
        """Raw counts (B, T, H, 2W) -> pose, action logits and progress for time t."""
        b, t, h, w2 = frames.shape
        emb = self.embed_frames(frames.reshape(b * t, h, w2))  # (B*T, E)
        return self.forward_embeddings(emb.view(b, t, -1))  # (B, T, E) -> heads

    def num_parameters(self) -> int:
        return sum(p.numel() for p in self.parameters())


def recency_prior(window: int) -> torch.Tensor:
    """Pool logits that give the newest frame's token half the weight at the start.

    Pose and progress are about time t, right after the newest frame; a uniform
    mean over a window that spans about one repetition is nearly the same at
    every phase, so with it the heads start out blind to where in the
    repetition t is. The weights stay learnable.
    """
    logits = torch.zeros(window + 1)  # class token, then frames oldest .. newest
    logits[-1] = math.log(window)  # e^log(T) = T, the sum of the other T tokens' e^0
    return logits


def _init_weights(module: nn.Module) -> None:
    if isinstance(module, nn.Linear):
        nn.init.normal_(module.weight, std=0.02)
        if module.bias is not None:
            nn.init.zeros_(module.bias)
