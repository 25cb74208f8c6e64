"""Import speed on one core: ``python -m scotti.importers.bench [--frames N] [--format F]``.

Builds a synthetic recording of another insole (a 16 x 8 grid per foot at
100 Hz by default, with MediaPipe-33 keypoints at 30 Hz in a camera frame
and one action segment; ``--format`` csv, npz or h5), imports it, and
prints source frames and output (16 Hz) frames per second, with the time
of each stage. BLAS is held to one thread; the rates are given per second
of wall time and per second of this process's CPU time (what one core
does, whatever else the machine is running).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # before numpy loads: one core's figure

import argparse  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from collections.abc import Sequence  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
from scotti.importers.config import config_from_dict  # noqa: E402
from scotti.importers.keypoint_sets import MEDIAPIPE33, SET_MAPPINGS  # noqa: E402
from scotti.importers.run import import_recording  # noqa: E402


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


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m scotti.importers.bench", description=__doc__)
    parser.add_argument("--frames", type=int, default=60_000, help="source frames")
    parser.add_argument("--grid", default="16x8", help="ROWSxCOLS per foot")
    parser.add_argument("--rate", type=float, default=100.0, help="source frame rate, Hz")
    parser.add_argument("--format", choices=("csv", "npz", "h5"), default="npz")
    args = parser.parse_args(argv)
    rows, cols = (int(x) for x in args.grid.split("x"))
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        raw = synthetic(folder, args.frames, rows, cols, args.rate, args.format)
        cfg = config_from_dict(raw)
        started, cpu_started = time.perf_counter(), time.process_time()
        report = import_recording(cfg, folder / "out.scotti")
        seconds = time.perf_counter() - started
        cpu = time.process_time() - cpu_started
    print(
        f"{args.format} {rows}x{cols} at {args.rate:g} Hz: {report.source_frames} source frames"
        f" -> {report.frames} frames at 16 Hz in {seconds:.2f} s wall, {cpu:.2f} s CPU"
    )
    print(
        f"  per wall second: {report.source_frames / seconds:,.0f} source frames/s, "
        f"{report.frames / seconds:,.0f} output frames/s"
    )
    print(
        f"  per CPU second (one core): {report.source_frames / cpu:,.0f} source frames/s, "
        f"{report.frames / cpu:,.0f} output frames/s"
    )
    print("  " + ", ".join(f"{k} {v:.2f} s" for k, v in report.seconds.items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
