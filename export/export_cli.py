"""``scotti export CHECKPOINT -o models/NAME.onnx [--int8] [--threads N]``.

Writes NAME.onnx (streaming step), NAME.window.onnx, NAME.card.json and
NAME.card.md (plus NAME.int8.onnx / NAME.int8.window.onnx with --int8), only
after onnxruntime agreed with torch; prints the differences it measured.
Exit 0 on success, 2 for a bad checkpoint or argument, 1 when a proof fails.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from scotti.export.errors import ExportError, ParityError
from scotti.export.onnx_export import export_checkpoint
from scotti.export.parity import format_report


def _threads(text: str) -> int:
    value = int(text)
    if value < 1:
        msg = f"threads must be >= 1, got {value}"
        raise argparse.ArgumentTypeError(msg)
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("checkpoint", type=Path, help="torch checkpoint written by scotti train")
    parser.add_argument(
        "-o", "--output", type=Path, required=True, help="step graph path, e.g. models/NAME.onnx"
    )
    parser.add_argument(
        "--int8", action="store_true", help="also write dynamically quantized int8 copies"
    )
    parser.add_argument(
        "--threads", type=_threads, default=1, help="onnxruntime threads for the proofs"
    )


def run(args: argparse.Namespace) -> int:
    try:
        result = export_checkpoint(
            args.checkpoint, args.output, int8=args.int8, threads=args.threads
        )
    except ParityError as exc:
        print(f"scotti export: parity check failed, nothing written: {exc}", file=sys.stderr)
        return 1
    except ExportError as exc:
        print(f"scotti export: {exc}", file=sys.stderr)
        return 2
    card = result.card
    print(
        f"exported {card['name']}: {card['parameters']:,} parameters, "
        f"T={card['config']['window']}, E={card['config']['embed_dim']}"
    )
    for kind, entry in card["files"].items():
        size = entry["bytes"] / 1e6
        print(f"  {kind:12s} {entry['file']}  {size:.2f} MB  sha256 {entry['sha256'][:16]}")
    print(f"  card         {result.paths.card_json.name}, {result.paths.card_md.name}")
    tol = card["parity"]["tolerance"]
    print(f"max abs difference, onnxruntime vs torch (atol {tol['atol']:g}, rtol {tol['rtol']:g}):")
    for line in format_report(result.parity):
        print(f"  {line}")
    if result.int8_drift:
        print("int8 drift against fp32 (max abs, measured, not bounded):")
        for line in format_report(result.int8_drift):
            print(f"  {line}")
    return 0
