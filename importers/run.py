"""One import from start to end: read, check, map onto the contract, write the session."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scotti.importers.config import ImportConfig
from scotti.importers.feet import resample_feet
from scotti.importers.labels import frame_actions, frame_labels, read_segments
from scotti.importers.pose import pose_frame, read_keypoints, to_world
from scotti.importers.session_out import ImportedFrames, write_imported
from scotti.importers.sources import LoadedPressure, load_pressure
from scotti.importers.timebase import Timeline, interpolate_points, plan_timeline
from scotti.models.contract import ACTIONS, FRAME_RATE_HZ, NO_ACTION


@dataclass
class ImportReport:
    """What went into the session file, and how long each part took."""

    path: str
    source_frames: int
    source_rate_hz: float
    frames: int
    segments: int
    duration_s: float
    labels: int = 0
    keypoints_mapped: list[str] = field(default_factory=list)
    keypoints_masked_share: float = 0.0  # of all keypoints in labelled frames
    actions: dict[str, int] = field(default_factory=dict)  # frames per action
    progress_frames: int = 0
    seconds: dict[str, float] = field(default_factory=dict)  # wall seconds per stage
    cpu_seconds: dict[str, float] = field(default_factory=dict)  # this process's CPU, per stage
    source: str = ""  # what the pressure file was, in a few words (vendor files)
    absent_feet: list[str] = field(default_factory=list)

    def lines(self) -> list[str]:
        out = [
            f"{self.path}: {self.frames} frames at 16 Hz ({self.duration_s:.1f} s) in "
            f"{self.segments} segment(s) from {self.source_frames} source frames at "
            f"{self.source_rate_hz:.3g} Hz; {self.labels} labels",
        ]
        if self.source:
            out.append(f"  pressure: {self.source}")
        for foot in self.absent_feet:
            out.append(
                f"  {foot} foot: absent from the file, no packets for it (a one-foot recording)"
            )
        if self.keypoints_mapped:
            out.append(
                f"  keypoints: {len(self.keypoints_mapped)} of 19 mapped, "
                f"{100 * self.keypoints_masked_share:.1f} % masked in labelled frames"
            )
        if self.actions:
            shown = ", ".join(f"{a} {n}" for a, n in self.actions.items())
            out.append(f"  actions (frames): {shown}; progress on {self.progress_frames} frames")
        return out


def import_recording(
    cfg: ImportConfig, output: str | Path, *, overwrite: bool = False
) -> ImportReport:
    """Import what ``cfg`` describes into the session file ``output``."""
    clock = _Stopwatch()
    pressure = load_pressure(cfg)
    source = pressure.feet
    clock.lap("read_pressure")
    timeline = plan_timeline(source.times)
    counts = resample_feet(source, timeline)
    clock.lap("resample_pressure")

    keypoints = None
    mapped: tuple[str, ...] = ()
    kp_info: dict[str, Any] | None = None
    if cfg.keypoints is not None:
        kp_source = read_keypoints(cfg)
        world = to_world(cfg.keypoints, kp_source)
        on_frames = interpolate_points(
            kp_source.times, world, timeline.times, cfg.keypoints.max_gap_s
        )
        keypoints = np.empty_like(on_frames)
        for index in range(len(timeline.source_ranges)):
            rows = timeline.segment == index
            keypoints[rows] = pose_frame(on_frames[rows])
        keypoints = keypoints.astype(np.float32)
        mapped = kp_source.mapped
        kp_info = {
            "file": kp_source.path.name,
            "set": cfg.keypoints.set,
            "mapped": list(mapped),
            "frames": int(kp_source.times.size),
            "units": cfg.keypoints.units,
            "up": cfg.keypoints.up,
            "time_offset_s": cfg.keypoints.time_offset_s,
        }
        clock.lap("keypoints")

    action = progress = repetition = None
    label_info: dict[str, Any] | None = None
    if cfg.labels is not None:
        if cfg.labels.segments is not None:
            seg_path = cfg.path(cfg.labels.segments)
            segments = read_segments(
                seg_path, cfg.labels, float(source.times[0]), float(source.times[-1])
            )
            action = frame_actions(timeline.times, segments)
            label_info = {"segments": seg_path.name, "count": len(segments)}
        else:
            assert cfg.labels.action is not None
            action = np.full(len(timeline), ACTIONS.index(cfg.labels.action), dtype=np.int64)
            label_info = {"action": cfg.labels.action}
        if keypoints is not None:
            action, progress, repetition = frame_labels(keypoints, action, timeline.segment)
        clock.lap("labels")

    frames = ImportedFrames(
        timeline.times, timeline.seq, counts, keypoints, action, progress, repetition
    )
    provenance = _provenance(pressure, timeline, kp_info, label_info)
    created = pressure.start_unix if pressure.start_unix is not None else _mtime(source.path)
    labels = write_imported(
        output,
        frames,
        device=cfg.device,
        created_unix=created,
        subject=_subject(cfg, Path(output), pressure),
        provenance=provenance,
        source_frames=pressure.source_frames,
        feet=source.feet,
        overwrite=overwrite,
    )
    clock.lap("write")
    report = ImportReport(
        path=str(output),
        source_frames=int(source.times.size),
        source_rate_hz=source.rate_hz,
        frames=len(timeline),
        segments=len(timeline.source_ranges),
        duration_s=len(timeline) / FRAME_RATE_HZ,
        labels=labels,
        keypoints_mapped=list(mapped),
        seconds=clock.laps,
        cpu_seconds=clock.cpu_laps,
        source=_describe(pressure),
        absent_feet=list(source.absent),
    )
    if keypoints is not None:
        has = np.isfinite(keypoints).all(axis=2)
        report.keypoints_masked_share = float(1.0 - has.mean()) if has.size else 0.0
    if action is not None:
        names, counts_per = np.unique(action, return_counts=True)
        report.actions = {
            ("none" if a == NO_ACTION else ACTIONS[a]): int(n)
            for a, n in zip(names.tolist(), counts_per.tolist(), strict=True)
        }
    if progress is not None:
        report.progress_frames = int(np.isfinite(progress).sum())
    return report


def _subject(cfg: ImportConfig, output: Path, pressure: LoadedPressure) -> dict[str, Any]:
    subject: dict[str, Any] = {"id": cfg.subject or output.stem, **pressure.subject}
    if cfg.mass_kg is not None:
        subject["mass_kg"] = cfg.mass_kg
    if cfg.height_m is not None:
        subject["height_m"] = cfg.height_m
    return subject


def _describe(pressure: LoadedPressure) -> str:
    """A vendor file in a few words: format, feet, grid or cells, units, scale, what was cut."""
    if pressure.format == "table":
        return ""
    p = pressure.provenance["pressure"]
    feet: list[str] = []
    scales: dict[str, None] = {}  # in the order met
    for foot, d in p["feet"].items():
        shape = " x ".join(map(str, d["grid"])) if "grid" in d else f"{d['cells']} cells"
        feet.append(f"{foot} {shape}")
        scales[_SCALES.get(d["method"], d["method"])] = None
        if d.get("scaled_to_file_total"):
            scales["each foot scaled to the file's total force"] = None
    text = f"{p['format']}, {', '.join(feet)}, {p['units']} ({'; '.join(scales)})"
    events = len(pressure.provenance.get("events", []))
    text += f", {events} events" if events else ""
    cut = pressure.provenance.get("vendor", {}).get("cut_s") or [0.0, 0.0]
    if any(cut):
        text += f"; cut {cut[0]:g} s at the start, {cut[1]:g} s at the end (one insole silent)"
    return text


_SCALES = {
    "units": "its units",
    "sensor_area": "newtons over each sensor's area",
    "body_mass": "scaled by --mass-kg",
}


def _mtime(path: Path) -> float:
    try:
        return float(path.stat().st_mtime)
    except OSError:
        return 0.0


def _provenance(
    pressure: LoadedPressure,
    timeline: Timeline,
    keypoints: dict[str, Any] | None,
    labels: dict[str, Any] | None,
) -> dict[str, Any]:
    times = pressure.feet.times
    return {
        **pressure.provenance,
        "counts": pressure.counts,
        "segments": [[float(times[a]), float(times[b])] for a, b in timeline.source_ranges],
        "keypoints": keypoints,
        "labels": labels,
    }


class _Stopwatch:
    def __init__(self) -> None:
        self.laps: dict[str, float] = {}
        self.cpu_laps: dict[str, float] = {}
        self._last = time.perf_counter()
        self._last_cpu = time.process_time()

    def lap(self, name: str) -> None:
        now, cpu = time.perf_counter(), time.process_time()
        self.laps[name] = now - self._last
        self.cpu_laps[name] = cpu - self._last_cpu
        self._last, self._last_cpu = now, cpu
