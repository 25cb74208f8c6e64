"""``scotti import [CONFIG.toml | RECORDING] -o OUT.scotti``: another recording into a session file.

    scotti import walk.toml -o data/real/p01-walk.scotti
    scotti import pedar_example.asc -o p01.scotti          # a vendor's export, by its header
    scotti import --pressure p.npz --grid 16x8 --counts-per-kpa 10 \\
                  --keypoints pose.csv --keypoint-set body25 --up=-y \\
                  --action walking --subject p01 -o p01.scotti

A TOML file describes everything (importers/config.py, importers/IMPORT.md);
the flags cover the simple cases and override the file's keys. A vendor's
export (novel pedar .asc, Tekscan F-Scan .asf, XSENSOR .csv, Moticon
OpenGo .txt, PhysioNet gaitpdb .txt[.gz]) is recognised by its own header
(``--format`` names it outright). Any mistake in a file is one line naming
the file, the line and the column, exit 2.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from scotti.firmware_protocol.overwrite import FORCE_HELP, REFUSED
from scotti.importers.errors import ImporterError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.description = __doc__
    parser.add_argument(
        "config",
        nargs="?",
        type=Path,
        help="import TOML, or a pressure recording (a vendor's export or a table)",
    )
    parser.add_argument(
        "-o", "--output", type=Path, required=True, help=f"session file to write ({REFUSED})"
    )
    parser.add_argument("--force", action="store_true", help=FORCE_HELP)
    parser.add_argument("--pressure", help="pressure file (a vendor's export, .csv, .npz, .h5)")
    parser.add_argument(
        "--format",
        choices=("auto", "table", "pedar", "fscan", "xsensor", "moticon", "gaitpdb"),
        help="the pressure file's format (default auto: from its own header)",
    )
    parser.add_argument(
        "--foot",
        choices=("left", "right"),
        help="which insole a one-insole file is, where the file cannot say (F-Scan)",
    )
    parser.add_argument(
        "--mass-kg",
        type=float,
        help="the wearer's mass: into the header, and the scale of a file that states none",
    )
    parser.add_argument("--grid", metavar="ROWSxCOLS", help="the source grid of one foot")
    parser.add_argument("--time-unit", choices=("s", "ms", "us", "ns"))
    scale = parser.add_mutually_exclusive_group()
    scale.add_argument("--counts-per-kpa", type=float, help="source units per kPa")
    scale.add_argument("--gain", type=float, help="source values are counts; times this")
    parser.add_argument("--keypoints", help="keypoint file (.csv, .npz, .h5)")
    parser.add_argument(
        "--keypoint-set", choices=("coco_wholebody", "mediapipe33", "body25", "custom")
    )
    parser.add_argument(
        "--up",
        choices=("+x", "-x", "+y", "-y", "+z", "-z", "auto"),
        help="the keypoints' up axis; a value with a sign wants '=': --up=-y",
    )
    parser.add_argument("--units", choices=("m", "cm", "mm"), help="keypoint units")
    parser.add_argument(
        "--floor",
        choices=("plane", "feet"),
        help="keypoints: one floor plane (default), or each frame stood on its feet "
        "(hip-centred coordinates such as MediaPipe's world landmarks)",
    )
    labels = parser.add_mutually_exclusive_group()
    labels.add_argument("--segments", help="CSV of start,end,action")
    labels.add_argument("--action", help="the one action of the whole recording")
    parser.add_argument("--subject", help="subject id (default: the output's stem)")


def overrides(args: argparse.Namespace) -> dict[str, Any]:
    """The flags as configuration keys (only those given)."""
    out: dict[str, Any] = {}
    pressure: dict[str, Any] = {}
    if args.pressure is not None:
        pressure["file"] = str(Path(args.pressure).resolve())
    if args.grid is not None:
        try:
            rows, cols = (int(x) for x in args.grid.lower().split("x"))
        except ValueError:
            msg = f"--grid wants ROWSxCOLS, e.g. 16x8, got {args.grid!r}"
            raise ImporterError(msg) from None
        pressure |= {"rows": rows, "cols": cols}
    if args.time_unit is not None:
        pressure["time_unit"] = args.time_unit
    if args.format is not None:
        pressure["format"] = args.format
    if args.foot is not None:
        pressure["foot"] = args.foot
    if pressure:
        out["pressure"] = pressure
    if args.counts_per_kpa is not None:
        out["counts"] = {"method": "per_kpa", "units_per_kpa": args.counts_per_kpa}
    if args.gain is not None:
        out["counts"] = {"method": "counts", "gain": args.gain}
    keypoints: dict[str, Any] = {}
    if args.keypoints is not None:
        keypoints["file"] = str(Path(args.keypoints).resolve())
    named = (("keypoint_set", "set"), ("up", "up"), ("units", "units"), ("floor", "floor"))
    for flag, key in named:
        if getattr(args, flag) is not None:
            keypoints[key] = getattr(args, flag)
    if keypoints:
        out["keypoints"] = keypoints
    if args.segments is not None:
        out["labels"] = {"segments": str(Path(args.segments).resolve())}
    if args.action is not None:
        out["labels"] = {"action": args.action}
    if args.subject is not None:
        out["subject"] = args.subject
    if args.mass_kg is not None:
        out["mass_kg"] = args.mass_kg
    return out


def run(args: argparse.Namespace) -> int:
    from scotti.importers.config import config_from_dict, load_config
    from scotti.importers.run import import_recording

    try:
        extra = overrides(args)
        if args.config is not None and not _is_toml(args.config):
            if args.pressure is not None:
                msg = f"{args.config}: a recording and --pressure; give one of them"
                raise ImporterError(msg)
            extra.setdefault("pressure", {})["file"] = str(args.config.resolve())
            cfg = config_from_dict(extra, name="the command line")
        elif args.config is not None:
            cfg = load_config(args.config, extra)
        else:
            cfg = config_from_dict(extra, name="the command line")
        if args.output.exists() and not args.force:
            msg = f"{args.output} exists; --force replaces it"
            raise ImporterError(msg)
        report = import_recording(cfg, args.output, overwrite=args.force)
    except ImporterError as exc:
        print(f"scotti import: {exc}", file=sys.stderr)
        return 2
    except MemoryError:  # a last resort: the readers check every size before allocating
        print(
            "scotti import: out of memory (the machine is busy, or the recording is too long)",
            file=sys.stderr,
        )
        return 2
    for line in report.lines():
        print(line)
    return 0


def _is_toml(path: Path) -> bool:
    return path.suffix.lower() == ".toml"
