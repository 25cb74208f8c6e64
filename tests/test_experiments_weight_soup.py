"""experiments/weight_soup.py: the mean of two checkpoints' weights, which export reads
as any checkpoint; checkpoints of other models are refused in one line."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

pytest.importorskip("torch")
import torch
from scotti.export.make_tiny import TINY_CONFIG, build_tiny, tiny_checkpoint
from scotti.export.model import Scotti, ScottiConfig
from scotti.export.onnx_export import load_checkpoint

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "experiments"))
import weight_soup


def _shifted(model: Scotti, by: float) -> Scotti:
    """A copy with every parameter moved by ``by`` (buffers as they were)."""
    other = Scotti(model.cfg)
    other.load_state_dict(model.state_dict())
    with torch.no_grad():
        for p in other.parameters():
            p.add_(by)
    return other


def _save(model: Scotti, path: Path) -> Path:
    ck = tiny_checkpoint(model)
    ck["trained_model"] = model.state_dict()
    torch.save(ck, path)
    return path


def test_the_soup_is_the_mean_and_exports_as_a_checkpoint(tmp_path: Path) -> None:
    a = build_tiny()
    b = _shifted(a, 0.25)
    out = tmp_path / "soup" / "best.pt"
    code = weight_soup.main(
        [str(_save(a, tmp_path / "a.pt")), str(_save(b, tmp_path / "b.pt")), "-o", str(out)]
    )
    assert code == 0
    souped = load_checkpoint(out).model.state_dict()
    for name, value in a.state_dict().items():
        if value.is_floating_point():
            expected = (value.double() + b.state_dict()[name].double()) / 2
            torch.testing.assert_close(souped[name].double(), expected, rtol=0, atol=1e-6)
    moved = [n for n, p in a.named_parameters() if not torch.equal(souped[n], p.detach())]
    assert moved  # the soup is neither source
    raw = torch.load(out, map_location="cpu", weights_only=True)
    assert raw["soup"] == [str(tmp_path / "a.pt"), str(tmp_path / "b.pt")]
    assert raw["trained_model"].keys() == raw["model"].keys()


def test_checkpoints_of_other_models_are_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    a = _save(build_tiny(), tmp_path / "a.pt")
    wider = Scotti(ScottiConfig(**{**TINY_CONFIG.to_dict(), "head_hidden": 48}))
    b = _save(wider, tmp_path / "b.pt")
    out = tmp_path / "soup.pt"
    assert weight_soup.main([str(a), str(b), "-o", str(out)]) == 2
    assert "config differs" in capsys.readouterr().err
    assert not out.exists()
    assert weight_soup.main([str(a), "-o", str(out)]) == 2
    assert "at least two" in capsys.readouterr().err
    assert weight_soup.main([str(a), str(tmp_path / "none.pt"), "-o", str(out)]) == 2
    assert "no such checkpoint" in capsys.readouterr().err
