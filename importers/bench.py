"""Import speed per format on one core: ``python -m scotti.importers.bench``.

    python -m scotti.importers.bench                        # csv, npz, h5; vendor samples
    python -m scotti.importers.bench --formats csv,npz      # the CSV figure and its baseline
    python -m scotti.importers.bench --frames 100000 --repeat 5 --formats csv
    python -m scotti.importers.bench --baseline csv --realdata ../shared/realdata

The table formats (CSV, ``.npz``, HDF5) import one synthetic recording of
another insole, written in each: a 16 x 8 grid per foot at 100 Hz by
default, MediaPipe-33 keypoints at 30 Hz in a camera frame and one action
segment. The vendor formats import a real sample of each from
``../shared/realdata`` (``VENDOR_SAMPLES``; a format without a sample, or
without the folder, gets a row saying so): pressure only, at the size the
vendor's file has.

Each row gives the source frames and the output (16 Hz) frames, the CPU
seconds of reading the pressure alone and of the whole import, and frames
per CPU second (what one core does; BLAS held to one thread): source frames
per CPU second of the read and of the whole import, and output frames per
CPU second of the whole import, also as a ratio to the baseline format's in
the same run (a ratio holds up better than a rate on a busy machine). Each
figure is the least CPU time of ``--repeat`` runs: other work on the machine
only ever adds to it. A line per format then says the whole import's two
rates in words, and a second table where its CPU time went, stage by stage.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # before numpy loads: one core's figure

import argparse  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from collections.abc import Sequence  # noqa: E402
from dataclasses import dataclass, field  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any, Final  # noqa: E402

import numpy as np  # noqa: E402
from scotti.importers.config import ImportConfig, config_from_dict  # noqa: E402
from scotti.importers.keypoint_sets import MEDIAPIPE33, SET_MAPPINGS  # noqa: E402
from scotti.importers.run import import_recording  # noqa: E402
from scotti.importers.sources import load_pressure  # noqa: E402
from scotti.importers.vendors import VENDOR_FORMATS  # noqa: E402

TABLE_FORMATS: Final = ("csv", "npz", "h5")
# One real file per vendor format, relative to the realdata folder. A new vendor
# reader adds its sample here; until then its row says it has none.
VENDOR_SAMPLES: Final[dict[str, str]] = {
    "pedar": "pressure-r/pedar_example.asc",
    "fscan": "pressure-r/fscan_testL.asf",
    "xsensor": "pressure-r/xsensor_data.csv",
    "moticon": "moticon-opengo/230927_102137.txt",
    "gaitpdb": "physionet-gaitpdb/GaCo01_01.txt.gz",
}
REALDATA: Final = Path(__file__).resolve().parents[1].parent / "shared" / "realdata"


@dataclass
class Row:
    """One format's figures (CPU seconds; None where the format was not run)."""

    format: str
    source: str
    source_frames: int = 0
    frames: int = 0
    read_cpu: float | None = None
    import_cpu: float | None = None
    stages: dict[str, float] = field(default_factory=dict)  # CPU seconds per stage
    note: str = ""

    def rate(self, frames: int, cpu: float | None) -> float | None:
        return frames / cpu if cpu else None


def synthetic(
    folder: Path, frames: int, rows: int, cols: int, rate: float, fmt: str
) -> dict[str, Any]:
    """Write the recording; returns the import configuration as a dict."""
    rng = np.random.default_rng(0)
    t = np.arange(frames) / rate
    r = (np.arange(rows) + 0.5) / rows
    centre = 0.5 + 0.3 * np.sin(2 * np.pi * t / 2.0)
    blob = np.exp(-0.5 * ((r[None, :, None] - centre[:, None, None]) / 0.15) ** 2)
    kpa = 100.0 * np.repeat(blob, cols, axis=2) + rng.uniform(0, 2, (frames, rows, cols))
    both = np.stack([kpa, 0.9 * kpa], axis=1)
    pressure: dict[str, Any] = {"rows": rows, "cols": cols}
    if fmt == "csv":
        path = folder / "pressure.csv"
        body = np.column_stack([t, both.reshape(frames, -1)])
        np.savetxt(path, body, delimiter=",", fmt="%.4f")
    elif fmt == "npz":
        path = folder / "pressure.npz"
        np.savez(path, time=t, left=both[:, 0], right=both[:, 1])
    else:
        import h5py

        path = folder / "pressure.h5"
        with h5py.File(path, "w") as f:
            f["time"], f["left"], f["right"] = t, both[:, 0], both[:, 1]
    pressure["file"] = str(path)
    tk = np.arange(0, t[-1], 1 / 30.0)
    points = np.full((tk.size, len(MEDIAPIPE33), 3), np.nan)
    stand: dict[str, tuple[float, float, float]] = {
        "left_hip": (0.0, 0.1, 0.9),
        "right_hip": (0.0, -0.1, 0.9),
    }
    stand |= {"left_heel": (-0.05, 0.1, 0.0), "right_heel": (-0.05, -0.1, 0.0)}
    stand |= {"left_big_toe": (0.18, 0.1, 0.0), "right_big_toe": (0.18, -0.1, 0.0)}
    for ours, (x, y, z) in stand.items():
        theirs = MEDIAPIPE33.index(SET_MAPPINGS["mediapipe33"][ours])
        sink = 0.15 * (1 - np.cos(2 * np.pi * tk / 2.0)) if "hip" in ours else 0.0
        camera = [np.full_like(tk, -y), 1.2 - (z - sink) + 0 * tk, np.full_like(tk, x + 3)]
        points[:, theirs] = np.stack(camera, axis=1)  # x right, y down, z ahead
    np.savez(folder / "pose.npz", time=tk, keypoints=points)
    (folder / "segments.csv").write_text(f"0.5,{t[-1] - 0.5:.3f},squat\n")
    return {
        "pressure": pressure,
        "counts": {"method": "per_kpa", "units_per_kpa": 1.0},
        "keypoints": {"file": str(folder / "pose.npz"), "set": "mediapipe33", "up": "-y"},
        "labels": {"segments": str(folder / "segments.csv")},
        "source_every_s": 1.0,
    }


def measure(row: Row, cfg: ImportConfig, output: Path, repeat: int = 1) -> Row:
    """Read the pressure alone, then import the whole recording: the least CPU seconds of
    ``repeat`` runs of each (and the stages of the quickest import)."""
    load_pressure(cfg)  # once untimed: the file in the page cache, the reader's modules loaded
    for _ in range(repeat):
        started = time.process_time()
        load_pressure(cfg)
        spent = time.process_time() - started
        row.read_cpu = spent if row.read_cpu is None else min(row.read_cpu, spent)
    for _ in range(repeat):
        started = time.process_time()
        report = import_recording(cfg, output, overwrite=True)
        spent = time.process_time() - started
        if row.import_cpu is None or spent < row.import_cpu:
            row.import_cpu, row.stages = spent, report.cpu_seconds
        row.source_frames, row.frames = report.source_frames, report.frames
    return row


def table_row(
    folder: Path, fmt: str, frames: int, grid: tuple[int, int], rate: float, repeat: int = 1
) -> Row:
    rows, cols = grid
    raw = synthetic(folder, frames, rows, cols, rate, fmt)
    row = Row(fmt, f"synthetic {rows} x {cols} at {rate:g} Hz, keypoints, labels")
    return measure(row, config_from_dict(raw), folder / f"{fmt}.scotti", repeat)


def vendor_row(folder: Path, fmt: str, realdata: Path, repeat: int = 1) -> Row:
    sample = VENDOR_SAMPLES.get(fmt)
    if sample is None:
        return Row(fmt, "-", note=f"no sample: add one to {__name__}.VENDOR_SAMPLES")
    path = realdata / sample
    if not path.is_file():
        return Row(fmt, sample, note=f"no {path} here")
    cfg = config_from_dict({"pressure": {"file": str(path)}, "source_every_s": 1.0})
    return measure(Row(fmt, sample), cfg, folder / f"{fmt}.scotti", repeat)


def _figure(value: float | None, digits: int = 0) -> str:
    return "-" if value is None else f"{value:,.{digits}f}"


def print_tables(rows: list[Row], baseline: str, repeat: int = 1) -> None:
    base = next((r for r in rows if r.format == baseline), None)
    base_rate = base.rate(base.frames, base.import_cpu) if base is not None else None
    print(
        "| format | source | source frames | output frames (16 Hz) | read (CPU s) "
        "| import (CPU s) | read: source frames / CPU s | import: source frames / CPU s "
        f"| import: output frames / CPU s | import: output frames / CPU s, / {baseline}'s |"
    )
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        if r.import_cpu is None:
            print(f"| {r.format} | {r.source} | {r.note} | | | | | | | |")
            continue
        out_rate = r.rate(r.frames, r.import_cpu)
        ratio = out_rate / base_rate if out_rate and base_rate else None
        print(
            f"| {r.format} | {r.source} | {r.source_frames:,} | {r.frames:,} "
            f"| {_figure(r.read_cpu, 3)} | {_figure(r.import_cpu, 3)} "
            f"| {_figure(r.rate(r.source_frames, r.read_cpu))} "
            f"| {_figure(r.rate(r.source_frames, r.import_cpu))} | {_figure(out_rate)} "
            f"| {_figure(ratio, 2)} |"
        )
    print()
    best = f", the least of {repeat} runs" if repeat > 1 else ""
    for r in rows:
        if r.import_cpu:
            print(
                f"{r.format}: {_figure(r.rate(r.source_frames, r.import_cpu))} source frames "
                f"and {_figure(r.rate(r.frames, r.import_cpu))} output (16 Hz) frames per CPU "
                f"second, the whole import ({r.import_cpu:.3f} CPU s{best})"
            )
    stages = list(dict.fromkeys(k for r in rows for k in r.stages))
    if stages:
        print()
        print("| format | " + " | ".join(f"{s} (CPU s)" for s in stages) + " |")
        print("|---|" + "---:|" * len(stages))
        for r in rows:
            if r.stages:
                cells = " | ".join(_figure(r.stages.get(s), 3) for s in stages)
                print(f"| {r.format} | {cells} |")


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m scotti.importers.bench",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    formats = (*TABLE_FORMATS, *VENDOR_FORMATS)
    parser.add_argument("--frames", type=int, default=20_000, help="source frames (tables)")
    parser.add_argument("--grid", default="16x8", help="ROWSxCOLS per foot (tables)")
    parser.add_argument("--rate", type=float, default=100.0, help="source frame rate, Hz")
    parser.add_argument(
        "--formats", default=",".join(formats), help=f"comma-separated, of {', '.join(formats)}"
    )
    parser.add_argument("--baseline", default="npz", help="the format the ratios are to")
    parser.add_argument(
        "--repeat", type=int, default=3, help="runs per format; the least CPU time counts"
    )
    parser.add_argument("--realdata", type=Path, default=REALDATA, help="vendor samples' folder")
    args = parser.parse_args(argv)
    chosen = [f.strip() for f in args.formats.split(",") if f.strip()]
    unknown = [f for f in chosen if f not in formats]
    try:
        grid = tuple(int(x) for x in args.grid.lower().split("x"))
    except ValueError:
        grid = ()
    if unknown or len(grid) != 2 or args.frames < 2 or args.repeat < 1:
        parser.error(
            f"--formats of {', '.join(formats)}; --grid ROWSxCOLS; --frames >= 2; --repeat >= 1"
        )
    rows: list[Row] = []
    with tempfile.TemporaryDirectory(prefix="scotti-import-bench-") as tmp:
        folder = Path(tmp)
        table_row(folder, "npz", 400, (2, 2), 100.0)  # untimed: the import's modules loaded
        for fmt in chosen:
            if fmt in TABLE_FORMATS:
                shape = (grid[0], grid[1])
                rows.append(table_row(folder, fmt, args.frames, shape, args.rate, args.repeat))
            else:
                rows.append(vendor_row(folder, fmt, args.realdata, args.repeat))
    print_tables(rows, args.baseline, args.repeat)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
