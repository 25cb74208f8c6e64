"""``scotti export CHECKPOINT -o models/NAME.onnx [--int8] [--calibrate SESSIONS...] [--force]``.

Writes NAME.onnx (streaming step), NAME.window.onnx, NAME.card.json and
NAME.card.md (plus NAME.int8.onnx / NAME.int8.window.onnx with --int8), only
after onnxruntime agreed with torch; prints the differences it measured.
With ``--calibrate``, the unfamiliar score is calibrated on those session
files (the checkpoint's training subjects for the statistics, its held-out
subjects for the threshold, as recorded, or with ``--calibrate-as-trained``
drawn through the foreign insoles and tempi the checkpoint was trained with;
export/ood_calibration.py) and both graphs carry the statistics; the same
held-out subjects fit the progress calibration (export/progress_fit.py). An
export whose files exist is refused unless ``--force``
(firmware_protocol/overwrite.py): it replaces them all, an int8 copy it does
not write again included. Exit 0 on success, 2 for a bad
checkpoint or argument or an export that exists, 1 when a proof fails.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from scotti.export.errors import ExportError, ParityError
from scotti.export.onnx_export import GraphPaths, export_checkpoint
from scotti.export.ood_calibration import Calibration
from scotti.export.parity import format_report
from scotti.firmware_protocol.overwrite import FORCE_HELP, OutputExistsError, refuse_existing


def _threads(text: str) -> int:
    value = int(text)
    if value < 1:
        msg = f"threads must be >= 1, got {value}"
        raise argparse.ArgumentTypeError(msg)
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("checkpoint", type=Path, help="torch checkpoint written by scotti train")
    parser.add_argument(
        "-o",
        "--output",
        type=Path,
        required=True,
        help="step graph path, e.g. models/NAME.onnx, written with NAME.window.onnx, "
        "NAME.card.json, NAME.card.md (and NAME.int8*.onnx): refused if any of them "
        "exists, unless --force",
    )
    parser.add_argument(
        "--force",
        action="store_true",
        help=f"{FORCE_HELP}; an int8 copy left from an earlier export is deleted "
        "when this one writes none",
    )
    parser.add_argument(
        "--int8", action="store_true", help="also write dynamically quantized int8 copies"
    )
    parser.add_argument(
        "--threads", type=_threads, default=1, help="onnxruntime threads for the proofs"
    )
    parser.add_argument(
        "--calibrate",
        type=Path,
        nargs="+",
        default=None,
        metavar="SESSIONS",
        help="session files or directories holding the checkpoint's training and held-out "
        "subjects: fit the unfamiliar score's statistics and threshold",
    )
    parser.add_argument(
        "--ood-percentile",
        type=float,
        default=99.0,
        help="threshold: this percentile of held-out windows' scores (default 99)",
    )
    parser.add_argument(
        "--ood-windows",
        type=_threads,
        default=Calibration.max_windows,
        help="training windows for the unfamiliar score's statistics, thinned evenly "
        f"(default {Calibration.max_windows}; more shrinks the covariance less: docs/ood.md)",
    )
    parser.add_argument(
        "--ood-held-out-windows",
        type=_threads,
        default=Calibration.held_out_windows,
        help="held-out windows for its thresholds, thinned evenly "
        f"(default {Calibration.held_out_windows}: every held-out window of a p1 run)",
    )
    parser.add_argument(
        "--calibrate-as-trained",
        action="store_true",
        help="draw the unfamiliar score's windows through the foreign insoles and tempi the "
        "checkpoint was trained with (default: as recorded; docs/ood.md says what it trades)",
    )
    parser.add_argument(
        "--progress-windows",
        type=int,
        default=20000,
        help="held-out windows the progress calibration is fitted on (default 20000; 0: none)",
    )
    parser.add_argument(
        "--cache-dir", type=Path, default=None, help="decoded-session cache (as scotti train)"
    )


def run(args: argparse.Namespace) -> int:
    try:  # before the checkpoint is read or a calibration replayed: a refusal is at once
        refuse_existing(GraphPaths.for_output(args.output).all(), force=args.force)
    except (ExportError, OutputExistsError) as exc:
        print(f"scotti export: {exc}", file=sys.stderr)
        return 2
    calibration = None
    if args.calibrate:
        if not 50.0 <= args.ood_percentile < 100.0:
            print("scotti export: --ood-percentile must be in [50, 100)", file=sys.stderr)
            return 2
        if args.progress_windows < 0:
            print("scotti export: --progress-windows must be >= 0", file=sys.stderr)
            return 2
        calibration = Calibration(
            tuple(args.calibrate),
            percentile=args.ood_percentile,
            max_windows=args.ood_windows,
            cache_dir=args.cache_dir,
            progress_windows=args.progress_windows,
            as_trained=args.calibrate_as_trained,
            held_out_windows=args.ood_held_out_windows,
        )
    try:
        result = export_checkpoint(
            args.checkpoint,
            args.output,
            int8=args.int8,
            threads=args.threads,
            calibration=calibration,
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
    if card.get("subnormal_weights_zeroed"):
        zeroed = card["subnormal_weights_zeroed"]
        print(f"  {zeroed:,} subnormal weights written as 0 (no output moves)")
    for kind, entry in card["files"].items():
        size = entry["bytes"] / 1e6
        print(f"  {kind:12s} {entry['file']}  {size:.2f} MB  sha256 {entry['sha256'][:16]}")
    print(f"  card         {result.paths.card_json.name}, {result.paths.card_md.name}")
    tol = card["parity"]["tolerance"]
    print(f"max abs difference, onnxruntime vs torch (atol {tol['atol']:g}, rtol {tol['rtol']:g}):")
    for line in format_report(result.parity):
        print(f"  {line}")
    ood = card.get("ood") or {}
    if ood.get("calibrated"):
        print(
            f"unfamiliar score: threshold {ood['threshold']:.2f} (p{ood['threshold_percentile']:g} "
            f"of {ood['held_out_windows']} {ood['held_out_split']} windows), statistics of "
            f"{ood['train_windows']} training windows, shrinkage {ood['shrinkage']:.3f}"
        )
        drawn = ood.get("windows_drawn") or {}
        if not drawn.get("as_recorded", True):
            print(
                f"  windows drawn as trained: {drawn['sensor_transfer']:g} through foreign "
                f"insoles, {drawn['tempo_stretch'] + drawn.get('tempo_extra', 0.0):g} "
                "at other tempi"
            )
        elif args.calibrate_as_trained:
            print(
                "  windows as recorded: the checkpoint names no foreign insoles or tempi "
                "in its training options"
            )
        if card.get("int8_ood"):
            int8_threshold = card["int8_ood"]["threshold"]
            print(f"  int8 graphs: their own statistics, threshold {int8_threshold:.2f}")
    else:
        print("unfamiliar score: not calibrated (give --calibrate SESSIONS)")
    progress = card.get("progress_calibration") or {}
    if progress.get("calibrated"):
        print(
            f"progress calibration: {', '.join(progress['frames'])} on {progress['windows']} "
            f"held-out windows, MSE {progress['mse_before']:.4f} -> {progress['mse_after']:.4f}"
        )
    elif args.calibrate:
        print(f"progress calibration: none ({progress.get('reason', 'not asked for')})")
    if result.int8_drift:
        print("int8 drift against fp32 (max abs, measured, not bounded):")
        for line in format_report(result.int8_drift):
            print(f"  {line}")
    return 0
