"""The SCOTTI torch module: config validation, shapes, separability, hard inputs."""

from __future__ import annotations

import json

import pytest

pytest.importorskip("torch")
import torch
from scotti.export.model import (
    ModelConfigError,
    Scotti,
    ScottiConfig,
    normalise,
)
from scotti.models import contract

pytestmark = pytest.mark.torch

TINY = ScottiConfig(embed_dim=32, layers=1, heads=2, conv_channels=(4, 8), head_hidden=32)


@pytest.fixture(scope="module")
def model() -> Scotti:
    torch.manual_seed(0)
    return Scotti(TINY).eval()


def test_paper_defaults() -> None:
    cfg = ScottiConfig()
    assert (cfg.window, cfg.embed_dim, cfg.frame_shape) == (40, 512, (32, 44))
    assert cfg.feedforward_dim == 2048
    assert ScottiConfig(ff_dim=100).feedforward_dim == 100


def test_config_round_trips_through_json() -> None:
    d = json.loads(json.dumps(TINY.to_dict()))
    assert ScottiConfig.from_dict(d) == TINY
    assert hash(ScottiConfig.from_dict(d)) == hash(TINY)


@pytest.mark.parametrize(
    ("changes", "fragment"),
    [
        ({"embed_dim": 30, "heads": 4}, "not divisible"),
        ({"window": 0}, "window"),
        ({"dropout": 1.0}, "dropout"),
        ({"conv_channels": (4,)}, "conv_channels"),
        ({"ff_dim": -1}, "ff_dim"),
        ({"rows": 2}, "too small"),
    ],
)
def test_bad_configs_are_refused(changes: dict[str, object], fragment: str) -> None:
    d = {**TINY.to_dict(), **changes}
    with pytest.raises(ModelConfigError, match=fragment):
        ScottiConfig.from_dict(d)


def test_unknown_config_key_is_refused() -> None:
    with pytest.raises(ModelConfigError, match="unknown config keys: colour"):
        ScottiConfig.from_dict({**TINY.to_dict(), "colour": "red"})


def test_normalise_maps_the_protocol_range_to_unit_interval() -> None:
    counts = torch.tensor([-5.0, 0.0, 1.0, float(contract.MAX_COUNT), 1e9])
    x = normalise(counts)
    assert x.tolist()[0] == 0.0
    assert x.tolist()[1] == 0.0
    assert 0.0 < x.tolist()[2] < 0.1
    assert x.tolist()[3] == pytest.approx(1.0)
    assert x.tolist()[4] == pytest.approx(1.0)  # out of range clamps, never explodes


def test_shapes(model: Scotti) -> None:
    frames = torch.rand(3, TINY.window, *TINY.frame_shape) * contract.MAX_COUNT
    with torch.no_grad():
        pose, logits, progress = model(frames)
    assert pose.shape == (3, contract.NUM_KEYPOINTS, 3)
    assert logits.shape == (3, contract.NUM_ACTIONS)
    assert progress.shape == (3,)


def test_window_equals_cached_frame_embeddings(model: Scotti) -> None:
    """The split the daemon relies on: embed each frame once, reuse it T times."""
    frames = torch.rand(2, TINY.window, *TINY.frame_shape) * contract.MAX_COUNT
    with torch.no_grad():
        whole = model(frames)
        one_by_one = torch.stack(
            [model.embed_frames(frames[:, i]) for i in range(TINY.window)], dim=1
        )
        split = model.forward_embeddings(one_by_one)
    for a, b in zip(whole, split, strict=True):
        torch.testing.assert_close(a, b, atol=1e-5, rtol=1e-5)


def test_frames_are_embedded_independently(model: Scotti) -> None:
    frames = torch.rand(4, *TINY.frame_shape) * contract.MAX_COUNT
    with torch.no_grad():
        together = model.embed_frames(frames)
        alone = model.embed_frames(frames[2:3])
    torch.testing.assert_close(together[2:3], alone, atol=1e-6, rtol=1e-5)


def hard_windows() -> torch.Tensor:
    t, (h, w2) = TINY.window, TINY.frame_shape
    zeros = torch.zeros(t, h, w2)  # flight phase of a jump
    saturated = torch.full((t, h, w2), float(contract.MAX_COUNT))
    hot = torch.zeros(t, h, w2)
    hot[:, 5, 30] = float(contract.MAX_COUNT)  # a single hot taxel
    mixed = torch.rand(t, h, w2) * contract.MAX_COUNT
    mixed[::3] = 0.0
    mixed[1::3] = float(contract.MAX_COUNT)
    return torch.stack([zeros, saturated, hot, mixed])


def test_hard_inputs_give_sane_outputs(model: Scotti) -> None:
    with torch.no_grad():
        pose, logits, progress = model(hard_windows())
    assert bool(torch.isfinite(pose).all())
    assert bool(torch.isfinite(logits).all())
    assert bool(((progress >= 0) & (progress <= 1)).all())
    probs = logits.softmax(dim=-1).sum(dim=-1)
    torch.testing.assert_close(probs, torch.ones(4), atol=1e-6, rtol=0)


def test_training_mode_backpropagates_to_every_parameter() -> None:
    torch.manual_seed(1)
    m = Scotti(TINY).train()
    pose, logits, progress = m(torch.rand(2, TINY.window, *TINY.frame_shape) * 100)
    (pose.sum() + logits.sum() + progress.sum()).backward()
    missing = [n for n, p in m.named_parameters() if p.grad is None]
    assert not missing
