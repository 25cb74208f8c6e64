"""Keypoint recordings: read, map onto our 19, and put in the contract's pose frame.

The pose frame (models/contract.py): metres, z up, the origin on the floor
under the mid-hip, x the way the person faces, y to their left. From any
source frame:

1. units to metres (``units``);
2. a proper rotation that takes the source's up axis (``up``: "+z" for most
   motion capture, "-y" for a camera frame with y down; "auto": the mean
   direction from the ankles to the shoulders) onto z; ``mirror`` flips a
   left-handed source (a mirrored video) first;
3. the floor to z = 0: ``floor = "plane"`` (the default), one floor for the
   whole recording (``floor_z``; "auto": the 5th percentile, over the
   recording, of the lowest foot point of each frame); ``floor = "feet"``,
   each frame lifted or lowered so that its lowest heel or toe is at z = 0;
4. per frame: the origin to the mid-hip's foot point, and a turn about z so
   that x is the facing direction, estimated from the hips (perpendicular to
   right hip -> left hip) and the feet (heel -> toes), averaged over 0.5 s.

A frame without both hips has no origin: all its keypoints stay masked.
Hips and feet must agree on the facing direction: a mirrored source makes
the toes point backwards from the hips, and is refused with a hint.

Coordinates that float, as MediaPipe's world landmarks do (their origin is
between the hips, so the hips never move and the feet rise towards them in a
squat), are refused under ``floor = "plane"`` with a hint to set ``floor =
"feet"``: when a torso point (mid-hip, mid-shoulder, the centroid) keeps to
one height while the lowest foot moves, or when the lowest foot is on the
floor in under half the frames. ``floor = "feet"`` recovers the hips' height
wherever a foot is on the floor (a squat, a lunge, walking); it cannot see a
flight (both feet in the air look like standing) nor a raised step (standing
on it looks like standing on the floor).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np
from scotti.importers.config import LENGTH_UNITS, TIME_UNITS, ImportConfig, KeypointsConfig
from scotti.importers.errors import InputError
from scotti.importers.keypoint_sets import SET_MAPPINGS, SETS, source_index
from scotti.importers.tables import CsvTable, load_arrays, read_csv
from scotti.models.contract import KEYPOINTS, KP, NUM_KEYPOINTS

# A person standing in the pose frame (metres; x forwards, y left, z up, floor at 0):
# the reference the pictures draw and the tests build foreign recordings from.
STANDING_POSE: Final[dict[str, tuple[float, float, float]]] = {
    "nose": (0.08, 0.0, 1.62),
    "left_shoulder": (0.0, 0.18, 1.42),
    "right_shoulder": (0.0, -0.18, 1.42),
    "left_elbow": (0.0, 0.22, 1.12),
    "right_elbow": (0.0, -0.22, 1.12),
    "left_wrist": (0.05, 0.22, 0.86),
    "right_wrist": (0.05, -0.22, 0.86),
    "left_hip": (0.0, 0.1, 0.92),
    "right_hip": (0.0, -0.1, 0.92),
    "left_knee": (0.02, 0.1, 0.5),
    "right_knee": (0.02, -0.1, 0.5),
    "left_ankle": (-0.02, 0.1, 0.08),
    "right_ankle": (-0.02, -0.1, 0.08),
    "left_big_toe": (0.18, 0.12, 0.0),
    "left_small_toe": (0.15, 0.16, 0.0),
    "left_heel": (-0.05, 0.1, 0.0),
    "right_big_toe": (0.18, -0.12, 0.0),
    "right_small_toe": (0.15, -0.16, 0.0),
    "right_heel": (-0.05, -0.1, 0.0),
}

_FEET_POINTS: Final = [KP[n] for n in KEYPOINTS if n.endswith(("heel", "toe", "ankle"))]
# What touches the floor: the ankles stand an unknown height above it.
_CONTACT_POINTS: Final = [KP[n] for n in KEYPOINTS if n.endswith(("heel", "toe"))]
_HEADING_SMOOTH_FRAMES: Final = 9  # 0.5 s at 16 Hz, centred
FLOOR_PERCENTILE: Final = 5.0


@dataclass(frozen=True)
class KeypointSource:
    """Keypoints as recorded, already mapped onto our 19 (NaN where unmapped or unseen)."""

    path: Path
    times: np.ndarray  # (N,) seconds on the pressure clock
    points: np.ndarray  # (N, 19, 3) source units and axes
    mapped: tuple[str, ...]  # which of our keypoints the source has


def read_keypoints(cfg: ImportConfig) -> KeypointSource:
    k = cfg.keypoints
    assert k is not None
    path = cfg.path(k.file)
    mapping = _mapping(cfg, k)
    if path.suffix.lower() == ".csv":
        times, names, raw, scores = _from_csv(path, k)
    else:
        times, names, raw, scores = _from_arrays(path, k)
    if names is None:
        names = SETS.get(k.set, tuple(str(i) for i in range(raw.shape[1])))
        if k.set in SETS and raw.shape[1] < len(names):
            problem = f"{raw.shape[1]} keypoints per frame; the set {k.set} has {len(names)}"
            raise InputError(path, problem)
    index = source_index(names, mapping)
    points = np.full((len(times), NUM_KEYPOINTS, 3), np.nan)
    for ours, theirs in enumerate(index):
        if theirs is None:
            continue
        if not 0 <= theirs < raw.shape[1]:
            wanted = mapping[KEYPOINTS[ours]]
            raise InputError(path, f"no keypoint {wanted!r} for {KEYPOINTS[ours]} in the file")
        points[:, ours] = raw[:, theirs]
        if scores is not None:
            points[scores[:, theirs] < k.min_score, ours] = np.nan
    times = times * TIME_UNITS[k.time_unit] + k.time_offset_s
    mapped = tuple(KEYPOINTS[i] for i, j in enumerate(index) if j is not None)
    return KeypointSource(path, times, points, mapped)


def _mapping(cfg: ImportConfig, k: KeypointsConfig) -> dict[str, str | int]:
    if k.set != "custom":
        return dict(SET_MAPPINGS[k.set])
    if k.mapping is not None:
        return dict(k.mapping)
    assert k.mapping_file is not None
    from scotti.importers.config import load_mapping

    return load_mapping(cfg.path(k.mapping_file))


# A point's confidence column, the first found: ours, then MediaPipe's.
_SCORE_SUFFIXES: Final = ("score", "visibility")


def _from_csv(
    path: Path, k: KeypointsConfig
) -> tuple[np.ndarray, tuple[str, ...] | None, np.ndarray, np.ndarray | None]:
    table = read_csv(path)
    time_col = table.column_of(k.time_column)
    times = table.values[:, time_col]
    _check_times(times, table, time_col)
    if table.header is None:  # positional: x, y, z per keypoint in the set's order
        rest = np.delete(table.values, time_col, axis=1)
        if rest.shape[1] % 3:
            raise InputError(path, f"{rest.shape[1]} coordinate columns is not 3 per keypoint")
        return times, None, rest.reshape(len(times), -1, 3), None
    names: list[str] = []
    for col in table.header:
        if col.endswith("_x") and col[:-2] not in names:
            names.append(col[:-2])
    if not names:
        raise InputError(path, "no NAME_x, NAME_y, NAME_z columns in the header", line=1)
    raw = np.full((len(times), len(names), 3), np.nan)
    scores = np.ones((len(times), len(names)))
    for i, name in enumerate(names):
        for axis, suffix in enumerate("xyz"):
            raw[:, i, axis] = table.values[:, table.column_of(f"{name}_{suffix}")]
        for suffix in _SCORE_SUFFIXES:
            if f"{name}_{suffix}" in table.header:
                scores[:, i] = table.values[:, table.header.index(f"{name}_{suffix}")]
                break
    bad = np.argwhere(np.isinf(raw))
    if bad.size:
        row, point, axis = (int(v) for v in bad[0])
        column = table.header.index(f"{names[point]}_{'xyz'[axis]}")
        raise table.fail(row, column, "an infinite coordinate")
    return times, tuple(names), raw, scores


def _check_times(times: np.ndarray, table: CsvTable, col: int) -> None:
    bad = np.flatnonzero(~np.isfinite(times))
    if bad.size:
        raise table.fail(int(bad[0]), col, "time stamp is not a number")
    back = np.flatnonzero(np.diff(times) <= 0)
    if back.size:
        i = int(back[0]) + 1
        kind = "duplicate" if times[i] == times[i - 1] else "earlier than the one before"
        raise table.fail(i, col, f"time stamp {kind}")


def _from_arrays(
    path: Path, k: KeypointsConfig
) -> tuple[np.ndarray, tuple[str, ...] | None, np.ndarray, np.ndarray | None]:
    arrays = load_arrays(path, [k.time_key, k.keypoints_key, k.names_key + "?"])
    times = np.asarray(arrays[k.time_key], dtype=np.float64).reshape(-1)
    raw = np.asarray(arrays[k.keypoints_key], dtype=np.float64)
    if raw.ndim != 3 or raw.shape[0] != times.size or raw.shape[2] not in (3, 4):
        problem = f"{k.keypoints_key} has shape {raw.shape}, expected ({times.size}, K, 3 or 4)"
        raise InputError(path, problem)
    bad = np.flatnonzero(~np.isfinite(times))
    if bad.size:
        raise InputError(path, "time stamp is not a number", column=f"{k.time_key}[{bad[0]}]")
    back = np.flatnonzero(np.diff(times) <= 0)
    if back.size:
        i = int(back[0]) + 1
        raise InputError(path, "time stamp not after the one before", column=f"{k.time_key}[{i}]")
    inf = np.argwhere(np.isinf(raw))
    if inf.size:
        where = ", ".join(str(int(v)) for v in inf[0])
        raise InputError(path, "an infinite coordinate", column=f"{k.keypoints_key}[{where}]")
    names = None
    if k.names_key in arrays:
        names = tuple(str(n.decode() if isinstance(n, bytes) else n) for n in arrays[k.names_key])
    scores = raw[:, :, 3] if raw.shape[2] == 4 else None
    return times, names, raw[:, :, :3], scores


# --- into the pose frame -----------------------------------------------------


def up_rotation(up: np.ndarray) -> np.ndarray:
    """A proper rotation (3, 3) taking the unit vector ``up`` onto +z."""
    u = up / np.linalg.norm(up)
    helper = np.array([1.0, 0.0, 0.0]) if abs(u[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = helper - helper.dot(u) * u
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    return np.stack([e1, e2, u])


_AXES: Final = {"x": 0, "y": 1, "z": 2}


def up_vector(cfg: KeypointsConfig, points: np.ndarray, path: Path) -> np.ndarray:
    if cfg.up != "auto":
        v = np.zeros(3)
        v[_AXES[cfg.up[1]]] = 1.0 if cfg.up[0] == "+" else -1.0
        return v
    shoulders = 0.5 * (points[:, KP["left_shoulder"]] + points[:, KP["right_shoulder"]])
    ankles = 0.5 * (points[:, KP["left_ankle"]] + points[:, KP["right_ankle"]])
    d = shoulders - ankles
    d = d[np.isfinite(d).all(axis=1)]
    if not d.size:
        problem = "up = 'auto' needs shoulders and ankles in some frame; give the up axis"
        raise InputError(path, problem)
    mean = (d / np.linalg.norm(d, axis=1, keepdims=True)).mean(axis=0)
    return np.asarray(mean / np.linalg.norm(mean))


def to_world(
    cfg: KeypointsConfig, source: KeypointSource, *, refuse_floating: bool = True
) -> np.ndarray:
    """(N, 19, 3) metres, z up, floor at z = 0 (still the source's heading and origin).

    ``refuse_floating=False`` skips the floating check of ``floor = "plane"``:
    only to measure what importing such coordinates as they are would give.
    """
    scaled = source.points * LENGTH_UNITS[cfg.units]
    if cfg.mirror:
        scaled = scaled * np.array([-1.0, 1.0, 1.0])  # any one axis: handedness flips
    world = scaled @ up_rotation(up_vector(cfg, scaled, source.path)).T
    if cfg.floor == "feet":
        world[..., 2] -= _floor_under_feet(world, source.path)[:, None]
        _check_handedness(world, source.path)
        return np.asarray(world)
    if cfg.floor_z == "auto":
        feet_z = world[:, _FEET_POINTS, 2]
        lowest = np.where(np.isfinite(feet_z), feet_z, np.inf).min(axis=1)
        lowest = lowest[np.isfinite(lowest)]
        if not lowest.size:
            problem = "floor_z = 'auto' needs heels, toes or ankles; give floor_z"
            raise InputError(source.path, problem)
        floor = float(np.percentile(lowest, FLOOR_PERCENTILE))
    else:
        floor = float(cfg.floor_z) * LENGTH_UNITS[cfg.units]
    world[..., 2] -= floor
    _check_handedness(world, source.path)
    if refuse_floating:
        _check_standing(world, source.path)
    return np.asarray(world)


def _lowest(world: np.ndarray, points: list[int]) -> np.ndarray:
    """(N,) the lowest z among ``points`` in each frame (NaN: none of them seen)."""
    z = world[:, points, 2]
    low = np.where(np.isfinite(z), z, np.inf).min(axis=1)
    return np.asarray(np.where(np.isfinite(low), low, np.nan))


def _floor_under_feet(world: np.ndarray, path: Path) -> np.ndarray:
    """(N,) each frame's floor: its lowest heel or toe (NaN: none seen, the frame stays masked)."""
    floor = _lowest(world, _CONTACT_POINTS)
    if not np.isfinite(floor).any():
        problem = "floor = 'feet' needs heels or toes (ankles are an unknown height above "
        problem += "the floor); map them, or use floor = 'plane'"
        raise InputError(path, problem)
    return floor


# The floating check (floor = "plane"), on the source's samples, metres.
FLOATING_FEET_RANGE_M: Final = 0.05  # the lowest foot moves less: nothing to tell (standing)
FLOATING_TORSO_SHARE: Final = 0.25  # a torso point moving under this share of that: floating
ON_FLOOR_M: Final = 0.10  # the lowest foot this close to the floor stands on it
ON_FLOOR_SHARE: Final = 0.5  # of frames: fewer on the floor, no common floor
_FLOOR_HINT: Final = 'set floor = "feet" (--floor feet) to stand each frame on its feet'


def _spread(z: np.ndarray) -> float:
    """The 5th to 95th percentile range: robust to a few glitches."""
    lo, hi = np.percentile(z, [5.0, 95.0])
    return float(hi - lo)


def _check_standing(world: np.ndarray, path: Path) -> None:
    """Refuse coordinates whose origin floats with the body instead of resting on a floor.

    On a floor, the lowest foot moves up only when the whole body does (a
    jump, a step up), so a torso point that keeps to one height while it
    moves means the origin is on the body: hip-centred (MediaPipe's world
    landmarks), root-relative, or centred on the body's centroid. Other
    floating origins show as feet that are seldom on any common floor.
    """
    lowest = _lowest(world, _FEET_POINTS)
    torso = {
        "mid-hip": 0.5 * (world[:, KP["left_hip"], 2] + world[:, KP["right_hip"], 2]),
        "mid-shoulder": 0.5
        * (world[:, KP["left_shoulder"], 2] + world[:, KP["right_shoulder"], 2]),
        "centroid": _mean_seen(world[..., 2]),
    }
    for name, z in torso.items():
        both = np.isfinite(lowest) & np.isfinite(z)
        if both.sum() < 2:
            continue
        feet, body = _spread(lowest[both]), _spread(z[both])
        if feet > FLOATING_FEET_RANGE_M and body < FLOATING_TORSO_SHARE * feet:
            problem = f"the keypoints float with the body: the {name} keeps within "
            problem += f"{1000 * body:.0f} mm of one height while the lowest foot moves "
            problem += f"{1000 * feet:.0f} mm (hip-centred coordinates?); {_FLOOR_HINT}"
            raise InputError(path, problem)
    seen = lowest[np.isfinite(lowest)]
    if seen.size < 2:
        return
    share = float((np.abs(seen) <= ON_FLOOR_M).mean())
    if share < ON_FLOOR_SHARE:
        problem = f"the lowest foot is within {1000 * ON_FLOOR_M:.0f} mm of one floor in only "
        problem += f"{100 * share:.0f} % of frames (a floating origin, or a wrong up or "
        problem += f"floor_z?); {_FLOOR_HINT}"
        raise InputError(path, problem)


def _mean_seen(z: np.ndarray) -> np.ndarray:
    """(N,) the mean over the points seen in each frame (NaN: none)."""
    seen = np.isfinite(z)
    total = np.where(seen, z, 0.0).sum(axis=1)
    count = seen.sum(axis=1)
    return np.asarray(np.where(count > 0, total / np.maximum(count, 1), np.nan))


MIRRORED_SHARE: Final = 0.5  # of frames where hips and feet disagree: refuse


def _check_handedness(world: np.ndarray, path: Path) -> None:
    """Refuse a source whose left and right are mirrored (toes behind the hips' forward)."""
    hips, feet = _facing_parts(world)
    agree = np.einsum("nk,nk->n", hips, feet)
    seen = np.isfinite(agree)
    if seen.sum() >= 1 and float((agree[seen] < 0).mean()) > MIRRORED_SHARE:
        share = 100 * float((agree[seen] < 0).mean())
        problem = f"left and right look mirrored: in {share:.0f} % of frames the toes point "
        problem += "backwards from the hips; check the keypoint set, or set mirror = true"
        raise InputError(path, problem)


def _facing_parts(world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit forward vectors on the floor from the hips and from the feet, (N, 2) each."""
    hips = world[:, KP["left_hip"], :2] - world[:, KP["right_hip"], :2]
    from_hips = _unit(np.stack([hips[:, 1], -hips[:, 0]], axis=1))  # left turned by -90 deg
    feet = []
    for side in ("left", "right"):
        heel = world[:, KP[f"{side}_heel"], :2]
        for toe in ("big_toe", "small_toe"):
            feet.append(_unit(world[:, KP[f"{side}_{toe}"], :2] - heel))
    stack = np.stack(feet)  # (4, N, 2)
    ok = np.isfinite(stack).all(axis=2)
    summed = np.where(ok[..., None], stack, 0.0).sum(axis=0)
    from_feet = _unit(np.where(ok.any(axis=0)[:, None], summed, np.nan))
    return from_hips, from_feet


def facing(world: np.ndarray) -> np.ndarray:
    """(N, 2) unit vectors on the floor the way each frame's person faces (NaN: unknown).

    The hips' and the feet's directions, equally weighted, summed over 0.5 s.
    """
    from_hips, from_feet = _facing_parts(world)
    summed = np.nan_to_num(from_hips) + np.nan_to_num(from_feet)
    smooth = _moving_sum(summed, _HEADING_SMOOTH_FRAMES)
    norm = np.linalg.norm(smooth, axis=1, keepdims=True)
    out = np.where(norm > 1e-9, smooth / np.where(norm > 1e-9, norm, 1.0), np.nan)
    return np.asarray(out)


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.asarray(np.where(n > 1e-9, v / np.where(n > 1e-9, n, 1.0), np.nan))


def _moving_sum(x: np.ndarray, width: int) -> np.ndarray:
    c = np.cumsum(np.vstack([np.zeros((1, x.shape[1])), x]), axis=0)
    half = width // 2
    hi = np.minimum(np.arange(x.shape[0]) + half + 1, x.shape[0])
    lo = np.maximum(np.arange(x.shape[0]) - half, 0)
    return np.asarray(c[hi] - c[lo])


def pose_frame(world: np.ndarray) -> np.ndarray:
    """(N, 19, 3) world (z up, floor 0) -> the contract's pose frame, per frame."""
    mid_hip = 0.5 * (world[:, KP["left_hip"]] + world[:, KP["right_hip"]])
    shifted = world - np.array([1.0, 1.0, 0.0]) * mid_hip[:, None, :]
    f = facing(world)
    c, s = f[:, 0:1], f[:, 1:2]
    x, y = shifted[..., 0], shifted[..., 1]
    out = np.stack([c * x + s * y, -s * x + c * y, shifted[..., 2]], axis=-1)
    no_origin = ~np.isfinite(mid_hip).all(axis=1) | ~np.isfinite(f).all(axis=1)
    out[no_origin] = np.nan
    return np.asarray(out)
