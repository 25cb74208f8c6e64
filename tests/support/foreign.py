"""Recordings of "other" insoles and pose systems, built in the tests' own shapes.

A person squats in place: a template standing pose (our 19 keypoints, pose
frame) whose upper body sinks ``depth`` metres and comes back every
``period_s``; pressure is a smooth load on a source grid of any size whose
centre of pressure moves heel <-> toes with the same period. Everything is
a closed form of time, so tests know what the importer must produce.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from scotti.importers.keypoint_sets import BODY25, COCO_WHOLEBODY, MEDIAPIPE33, SET_MAPPINGS
from scotti.importers.pose import STANDING_POSE
from scotti.models.contract import KEYPOINTS, KP

# Standing, facing +x, left = +y, feet flat on the floor (z = 0), metres.
TEMPLATE = STANDING_POSE
UPPER = {"nose", "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist"}
UPPER |= {"right_wrist", "left_hip", "right_hip"}


def squat_pose(times: np.ndarray, period_s: float = 2.0, depth: float = 0.3) -> np.ndarray:
    """(N, 19, 3) pose frame: the upper body sinks by depth*(1 - cos)/2, knees half as much."""
    base = np.array([TEMPLATE[name] for name in KEYPOINTS])
    sink = depth * 0.5 * (1.0 - np.cos(2.0 * np.pi * times / period_s))
    out = np.repeat(base[None], times.size, axis=0)
    for name in UPPER:
        out[:, KP[name], 2] -= sink
    for name in ("left_knee", "right_knee"):
        out[:, KP[name], 2] -= 0.5 * sink
    return out


def to_camera(
    pose: np.ndarray, heading: float = 0.7, at: Sequence[float] = (0.4, -0.3)
) -> np.ndarray:
    """Pose frame -> a camera frame (x right, y down, z forward, 1.2 m up): metres."""
    c, s = np.cos(heading), np.sin(heading)
    world = pose.copy()
    world[..., 0] = c * pose[..., 0] - s * pose[..., 1] + at[0]
    world[..., 1] = s * pose[..., 0] + c * pose[..., 1] + at[1]
    cam = np.empty_like(world)
    cam[..., 0] = -world[..., 1]
    cam[..., 1] = -(world[..., 2] - 1.2)
    cam[..., 2] = world[..., 0] + 3.0
    return cam


def in_set(ours: np.ndarray, set_name: str) -> np.ndarray:
    """(N, 19, 3) ours -> (N, K, 3) in a named set's order, NaN for points we do not know."""
    names = {"coco_wholebody": COCO_WHOLEBODY, "mediapipe33": MEDIAPIPE33, "body25": BODY25}
    order = names[set_name]
    inverse = {theirs: mine for mine, theirs in SET_MAPPINGS[set_name].items()}
    out = np.full((ours.shape[0], len(order), 3), np.nan)
    for i, name in enumerate(order):
        if name in inverse:
            out[:, i] = ours[:, KP[inverse[name]]]
    return out


def pressure_frames(times: np.ndarray, rows: int, cols: int, period_s: float = 2.0) -> np.ndarray:
    """(N, 2, rows, cols) kPa, toes at row 0, medial at column 0 (our orientation)."""
    r = (np.arange(rows) + 0.5) / rows
    c = (np.arange(cols) + 0.5) / cols
    centre = 0.3 + 0.4 * 0.5 * (1.0 - np.cos(2.0 * np.pi * times / period_s))  # 0 toes .. 1 heel
    blob = np.exp(-0.5 * ((r[None, :, None] - centre[:, None, None]) / 0.15) ** 2)
    blob = blob * np.exp(-0.5 * ((c[None, None, :] - 0.45) / 0.25) ** 2)
    kpa = 120.0 * blob
    return np.stack([kpa, 0.8 * kpa], axis=1)


def write_pressure_csv(path: Path, times_ms: np.ndarray, frames: np.ndarray) -> None:
    """Header + one line per frame: time (ms), then left, then right, row-major."""
    n, _, rows, cols = frames.shape
    names = ["t_ms"] + [f"{f}{r}_{c}" for f in "LR" for r in range(rows) for c in range(cols)]
    body = np.column_stack([times_ms, frames.reshape(n, -1)])
    lines = [",".join(names)] + [",".join(f"{v:.6g}" for v in row) for row in body]
    path.write_text("\n".join(lines) + "\n")


def write_keypoints_csv(
    path: Path, times_s: np.ndarray, points: np.ndarray, names: Sequence[str]
) -> None:
    """Header ``time, NAME_x, NAME_y, NAME_z, ...``; NaN written as empty-free 'nan'."""
    header = ["time"] + [f"{n}_{a}" for n in names for a in "xyz"]
    body = np.column_stack([times_s, points.reshape(points.shape[0], -1)])
    lines = [",".join(header)] + [",".join(f"{v:.6g}" for v in row) for row in body]
    path.write_text("\n".join(lines) + "\n")
