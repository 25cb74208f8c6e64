"""The tiny seeded model every other room's tests run: ``python -m scotti.export.make_tiny DIR``.

Writes DIR/scotti-tiny.onnx (step), .window.onnx, .card.json, .card.md and
the checkpoint DIR/scotti-tiny.pt, all together well under 1 MB. The weights
are random but seeded, and spread wider than a fresh model's so that the
outputs actually depend on the input (a parity check on a model whose outputs
are constant would prove little).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import torch
from scotti.export.errors import ExportError
from scotti.export.model import Scotti, ScottiConfig
from scotti.export.onnx_export import Checkpoint, ExportResult, export_model
from scotti.export.parity import format_report
from torch import nn

TINY_CONFIG = ScottiConfig(
    embed_dim=32, layers=1, heads=2, conv_channels=(4, 8), head_hidden=32, dropout=0.0
)
TINY_SEED = 20240617
TINY_NAME = "scotti-tiny"
TINY_TRAINING_DATA = f"none: random weights from make_tiny (seed {TINY_SEED}), for tests only"


def build_tiny() -> Scotti:
    """The same weights on every run and machine (CPU, seeded, fixed init order)."""
    torch.manual_seed(TINY_SEED)
    model = Scotti(TINY_CONFIG)
    with torch.no_grad():
        for module in model.modules():
            if isinstance(module, nn.Linear | nn.Conv2d):
                module.reset_parameters()  # torch's fan-in uniform, biases included
            elif isinstance(module, nn.LayerNorm | nn.BatchNorm1d):
                module.weight.uniform_(0.5, 1.5)
                module.bias.uniform_(-0.2, 0.2)
            if isinstance(module, nn.BatchNorm1d):  # running stats other than the identity
                assert module.running_mean is not None
                assert module.running_var is not None
                module.running_mean.normal_(0.0, 0.05)
                module.running_var.uniform_(0.005, 0.02)  # amplifies, as trained ones do
        nn.init.normal_(model.class_token, std=1.0)
        nn.init.normal_(model.positions, std=0.5)
        nn.init.normal_(model.pool_weights, std=1.0)
    return model.eval()


def tiny_checkpoint(model: Scotti) -> dict[str, object]:
    return {
        "config": model.cfg.to_dict(),
        "model": model.state_dict(),
        "training_data": TINY_TRAINING_DATA,
        "metrics": None,
        "epoch": 0,
    }


def make_tiny(directory: Path) -> ExportResult:
    model = build_tiny()
    directory.mkdir(parents=True, exist_ok=True)
    torch.save(tiny_checkpoint(model), directory / f"{TINY_NAME}.pt")
    ckpt = Checkpoint(model=model, training_data=TINY_TRAINING_DATA, epoch=0)
    return export_model(ckpt, directory / f"{TINY_NAME}.onnx")


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m scotti.export.make_tiny")
    parser.add_argument("directory", type=Path, help="where to write scotti-tiny.*")
    args = parser.parse_args(argv)
    try:
        result = make_tiny(args.directory)
    except ExportError as exc:
        print(f"make_tiny: {exc}", file=sys.stderr)
        return 2
    for line in format_report(result.parity):
        print(line)
    files = [result.paths.step, result.paths.window, result.paths.card_json, result.paths.card_md]
    files.append(args.directory / f"{TINY_NAME}.pt")
    total = sum(p.stat().st_size for p in files)
    print(f"wrote {len(files)} files, {total / 1024:.0f} KiB, to {args.directory}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
