"""Feet from footprints: each foot stands on plants and swings between them.

A ``Plant`` is one stance of one foot: where the flat foot's ankle is, on
which surface, from when to when, and how the foot rolls in and out of it
(heel strike then flat foot then toe off for walking; toe first for
backward walking; flat for a side step). Between two plants the foot swings
on a cubic path lifted by a bump: with zero velocity at both ends (C1), or,
for walking, leaving and striking the floor with some vertical speed. The
pelvis can follow the feet: ``support_path`` averages the standing feet and
smooths them over about one step.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scotti.sim.actions.curves import box_smooth, bump, ease, hermite
from scotti.sim.skeleton import Body, ankle_on_pivot, foot_points

Array = npt.NDArray[np.float64]

HEEL, TOE, FLAT = "heel", "toe", "flat"
_PIVOT_INDEX = {HEEL: 0, TOE: 1}


@dataclass(frozen=True)
class Plant:
    """One stance of one foot. Pitch > 0 lifts the toes; times in seconds."""

    t_on: float
    t_off: float
    xy: tuple[float, float]  # the flat foot's ankle, world x, y
    yaw: float
    floor_z: float = 0.0
    strike: str = FLAT  # pivot while landing: heel, toe or flat
    strike_pitch: float = 0.0
    strike_s: float = 0.0
    release: str = FLAT  # pivot while leaving: toe, heel or flat
    release_pitch: float = 0.0
    release_s: float = 0.0
    lift_before: float = 0.05  # swing height (m) on the way to this plant
    swing_pitch: float = 0.0  # extra pitch at mid-swing on the way here
    # Lift profile sin(pi s) ** lift_power: 2 leaves and lands with zero vertical
    # speed (C1); 1 lifts off and strikes with some, as a walking heel does.
    lift_power: float = 2.0


@dataclass(frozen=True)
class FootTrack:
    """One foot over a segment: ankle (N, 3), yaw, pitch, stance flag, ground."""

    ankle: Array
    yaw: Array
    pitch: Array
    stance: npt.NDArray[np.bool_]
    ground_z: Array


def _stance_pose(body: Body, side: int, plant: Plant, t: Array) -> tuple[Array, Array]:
    """Ankle (M, 3) and pitch (M,) while standing on ``plant`` at times ``t``."""
    m = len(t)
    pitch = np.zeros(m)
    pivot = np.full(m, FLAT, dtype=object)
    if plant.strike != FLAT and plant.strike_s > 0:
        s = (t - plant.t_on) / plant.strike_s
        rolling = s < 1.0
        pitch[rolling] = plant.strike_pitch * (1.0 - ease(s[rolling]))
        pivot[rolling] = plant.strike
    if plant.release != FLAT and plant.release_s > 0:
        s = (t - (plant.t_off - plant.release_s)) / plant.release_s
        rolling = s > 0.0
        pitch[rolling] = plant.release_pitch * ease(s[rolling])
        pivot[rolling] = plant.release
    yaw = np.full(m, plant.yaw)
    flat_ankle = np.array([*plant.xy, plant.floor_z + body.foot_height])
    ankle = np.tile(flat_ankle, (m, 1))
    for name, index in _PIVOT_INDEX.items():
        on = pivot == name
        if on.any():
            point = foot_points(body, side, flat_ankle[None], yaw[:1], np.zeros(1))[0, index]
            ankle[on] = ankle_on_pivot(
                body, side, np.tile(point, (int(on.sum()), 1)), index, yaw[on], pitch[on]
            )
    return ankle, pitch


def foot_track(body: Body, side: int, plants: list[Plant], t: Array) -> FootTrack:
    """Evaluate one foot at times ``t``; plants are in time order and must not overlap."""
    m = len(t)
    ankle = np.zeros((m, 3))
    yaw = np.zeros(m)
    pitch = np.zeros(m)
    stance = np.zeros(m, dtype=bool)
    ground = np.zeros(m)
    first, last = plants[0], plants[-1]
    # Before the first plant and after the last the foot stands on them.
    windows = [(p.t_on, p.t_off, p) for p in plants]
    windows[0] = (-np.inf, first.t_off, first)
    windows[-1] = (windows[-1][0], np.inf, last)
    for start, end, plant in windows:
        on = (t >= start) & (t <= end)
        ankle[on], pitch[on] = _stance_pose(body, side, plant, t[on])
        yaw[on] = plant.yaw
        stance[on] = True
        ground[on] = plant.floor_z
    for before, after in itertools.pairwise(plants):
        on = (t > before.t_off) & (t < after.t_on)
        if not on.any():
            continue
        ends = np.array([before.t_off, after.t_on])
        a0, p0 = _stance_pose(body, side, before, ends[:1])
        a1, p1 = _stance_pose(body, side, after, ends[1:])
        s = (t[on] - before.t_off) / (after.t_on - before.t_off)
        path = hermite(s, [0.0, 1.0], np.stack([a0[0], a1[0]]))
        rise = max(before.floor_z, after.floor_z) - min(before.floor_z, after.floor_z)
        lift = np.sin(np.pi * np.clip(s, 0.0, 1.0)) ** after.lift_power
        path[:, 2] += (after.lift_before + 0.6 * rise) * lift
        ankle[on] = path
        pitch[on] = hermite(s, [0.0, 1.0], [p0[0], p1[0]]) + after.swing_pitch * bump(s)
        yaw[on] = before.yaw + (after.yaw - before.yaw) * ease(s)
        # The surface under a swinging foot: whichever it is above.
        ground[on] = np.where(s < 0.5, before.floor_z, after.floor_z)
    return FootTrack(ankle, yaw, pitch, stance, ground)


def support_path(
    body: Body, feet: tuple[FootTrack, FootTrack], smooth_frames: int, swing_weight: float = 0.0
) -> Array:
    """Pelvis (N, 3): the standing feet's centre, smoothed, raised to hip height.

    A swinging foot counts with ``swing_weight`` (0: only standing feet pull
    the pelvis, which sways over each; 1: the plain middle of the feet).
    """
    weight = np.stack([np.where(f.stance, 1.0, swing_weight) for f in feet], axis=1)  # (N, 2)
    weight[weight.sum(axis=1) == 0] = 1.0  # both in the air: their middle
    points = np.stack([f.ankle for f in feet], axis=1)  # (N, 2, 3)
    points[..., 2] = np.stack([f.ground_z for f in feet], axis=1)
    raw = (weight[..., None] * points).sum(axis=1) / weight.sum(axis=1, keepdims=True)
    centre = box_smooth(raw, smooth_frames)
    # The centred filter starts moving before the first step and settles after
    # the last; pull both ends back onto the stand so segments join exactly.
    ramp = np.arange(len(raw)) / max(smooth_frames, 1)
    centre += (raw[0] - centre[0]) * (1.0 - ease(ramp))[:, None]
    centre += (raw[-1] - centre[-1]) * (1.0 - ease(ramp[::-1]))[:, None]
    centre[:, 2] += body.stand_hip_z
    return np.asarray(centre, dtype=np.float64)
