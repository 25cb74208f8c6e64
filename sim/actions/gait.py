"""Walking, backward walking, side walking and walking in place.

For these four a repetition is one step (one foot's swing), as the progress
labeller cuts them: by heel distance (walking, side walking), heel height
(in place) or heel displacement (backward). Walking is built from a gait
cycle with stance 60 %, double support 2 x 10 %, heel strike -> flat foot ->
heel rise -> toe off; the pelvis follows the standing feet and its height
an inverted pendulum (``pendulum.py``). Backward walking has
its own gait in ``backward.py``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scotti.models.contract import ACTIONS
from scotti.sim.actions.base import (
    ELBOW_REST,
    TOE_OUT,
    ActionSpec,
    Context,
    Place,
    Segment,
    finalize,
    neutral,
)
from scotti.sim.actions.curves import ease, hermite
from scotti.sim.actions.footsteps import FLAT, HEEL, TOE, FootTrack, Plant, foot_track, support_path
from scotti.sim.actions.pendulum import pendulum_height
from scotti.sim.skeleton import LEFT, RIGHT, Array, PoseParams, axes

STANCE = 0.6  # share of the gait cycle a foot stands (Winter; Perry)
STEP_LENGTH = 0.38  # x height: comfortable step length (0.67 m at 1.75 m)
SETTLE_S = 0.5  # after the closing step, before the segment ends
START_S = 0.3  # weight shift before the first swing
LEAD_AT_STRIKE = [0.1, 0.2]


def steps_for(spec: ActionSpec, step_s: float, least: int = 2) -> int:
    """Steps asked for: ``reps``, or as many as fit ``duration_s``."""
    if spec.reps is not None:
        return max(least, spec.reps)
    return max(least, round((spec.duration_s or 0.0) / step_s))


def walking(ctx: Context, spec: ActionSpec, place: Place) -> Segment:
    return _walk(ctx, spec, place, ACTIONS.index("walking"), 1.0, 1.0, 0.3, -0.6, 0.04)


def _walk(
    ctx: Context,
    spec: ActionSpec,
    place: Place,
    action: int,
    length_scale: float,
    cadence_scale: float,
    strike_pitch: float,
    release_pitch: float,
    lean: float,
) -> Segment:
    body, subject = ctx.body, ctx.subject
    step_s = 60.0 / (subject.cadence_spm * cadence_scale * spec.tempo)
    steps = steps_for(spec, step_s)
    length = spec.step_length_m or STEP_LENGTH * body.height * length_scale
    durations = ctx.rep_durations(step_s, 1.0, steps)
    lengths = length * np.clip(ctx.jitter(0.03, steps), 0.9, 1.1)
    first = int(ctx.rng.integers(2))  # which foot swings first
    swinging = [(first + k) % 2 for k in range(steps)]
    lengths *= np.array([1.0 + (0.5 if s == RIGHT else -0.5) * subject.asymmetry for s in swinging])
    toe_off = START_S + np.r_[0.0, np.cumsum(durations[:-1])]
    heel_strike = toe_off + (1.0 - STANCE) * 2 * durations
    # Forward position of each step's foot: step k lands one step ahead of the
    # other foot; the last step closes beside it.
    forward = np.zeros(steps)
    ahead = 0.0
    for k in range(steps - 1):
        ahead = ahead + lengths[k]
        forward[k] = ahead
    forward[-1] = ahead
    plants: list[list[Plant]] = [[], []]
    for side in (LEFT, RIGHT):
        lateral = (0.5 if side == LEFT else -0.5) * body.hip_spacing
        yaw = place.heading + (TOE_OUT if side == LEFT else -TOE_OUT)
        plants[side].append(Plant(0.0, 0.0, place.xy(0.0, lateral), yaw))
    for k, side in enumerate(swinging):
        last = k == steps - 1
        lateral = (0.5 if side == LEFT else -0.5) * body.hip_spacing
        yaw = place.heading + (TOE_OUT if side == LEFT else -TOE_OUT)
        before = plants[side][-1]
        release_s = min(0.5 * durations[k], 0.8 * (toe_off[k] - before.t_on))
        plants[side][-1] = _with_release(before, toe_off[k], release_pitch, release_s)
        plants[side].append(
            Plant(
                heel_strike[k],
                np.inf,
                place.xy(forward[k], lateral),
                yaw,
                strike=HEEL,
                strike_pitch=strike_pitch * (0.5 if last else 1.0),
                strike_s=0.24 * durations[k],
                lift_before=0.05,
                lift_power=1.0,
            )
        )
    end_s = heel_strike[-1] + SETTLE_S
    t = ctx.times(end_s)
    feet = (foot_track(body, LEFT, plants[LEFT], t), foot_track(body, RIGHT, plants[RIGHT], t))
    envelope = ease(t / START_S) * ease((end_s - t) / SETTLE_S)
    p = _drive(ctx, place, t, feet, round(step_s * ctx.rate_hz))
    # Forwards the pelvis is half-way between the feet at each heel strike;
    # sideways it sways over the stance foot (``support_path``).
    f, _ = axes(place.heading)
    strikes = heel_strike[:-1]
    middles = 0.5 * (forward[:-1] + np.r_[0.0, forward[:-2]])
    knot_t = np.r_[0.0, strikes, end_s - SETTLE_S, end_s]
    knot_u = np.r_[0.0, middles, forward[-1], forward[-1]]
    knot_v = np.gradient(knot_u, knot_t)
    knot_v[[0, -2, -1]] = 0.0
    along = hermite(t, knot_t, knot_u, knot_v)
    lateral = (p.pelvis[:, :2] - np.array([place.x, place.y])) @ f[:2]
    pelvis = p.pelvis.copy()
    pelvis[:, :2] += (along - lateral)[:, None] * f[:2]
    p = p.replace(lean=lean * envelope, pelvis=pelvis)
    ground = np.stack([f.ground_z for f in feet], axis=1)
    p = p.replace(pelvis=pendulum_height(body, p, t, ground, end_s))
    p = _arm_swing(p, feet, place.heading, length, 0.35)
    end = Place(*place.xy(forward[-1], 0.0), place.heading, place.floor_z)
    return Segment(finalize(body, p), np.full(len(t), action, dtype=np.int64), end, ground)


def _with_release(plant: Plant, t_off: float, pitch: float, release_s: float) -> Plant:
    """The plant, left at ``t_off`` rolling over the toes by ``pitch`` (or flat)."""
    release = TOE if pitch < 0 else FLAT
    return replace(plant, t_off=t_off, release=release, release_pitch=pitch, release_s=release_s)


def _drive(
    ctx: Context, place: Place, t: Array, feet: tuple[FootTrack, FootTrack], smooth: int
) -> PoseParams:
    """Neutral pose with the feet from ``feet`` and the pelvis following them."""
    p = neutral(ctx.body, place, len(t))
    return p.replace(
        pelvis=support_path(ctx.body, feet, max(1, smooth)),
        ankle=np.stack([feet[LEFT].ankle, feet[RIGHT].ankle], axis=1),
        foot_yaw=np.stack([feet[LEFT].yaw, feet[RIGHT].yaw], axis=1),
        foot_pitch=np.stack([feet[LEFT].pitch, feet[RIGHT].pitch], axis=1),
    )


def _arm_swing(
    p: PoseParams, feet: tuple[FootTrack, FootTrack], heading: float, span: float, amp: float
) -> PoseParams:
    """Each arm swings with the opposite leg: forwards when that foot is ahead."""
    f, _ = axes(heading)
    ahead = (feet[RIGHT].ankle - feet[LEFT].ankle) @ f  # right foot ahead of left, metres
    swing = amp * np.clip(ahead / max(span, 1e-6), -1.0, 1.0)
    flex = np.stack([swing, -swing], axis=1)
    elbow = ELBOW_REST + 0.4 * np.maximum(flex, 0.0)
    return p.replace(shoulder_flex=flex, elbow_flex=elbow)


def in_place_walking(ctx: Context, spec: ActionSpec, place: Place) -> Segment:
    """Marching on the spot: knees lift by turns, the feet land where they were."""
    body, subject = ctx.body, ctx.subject
    step_s = 60.0 / (0.9 * subject.cadence_spm * spec.tempo)
    steps = steps_for(spec, step_s, least=1)
    durations = ctx.rep_durations(step_s, 1.0, steps)
    depth = subject.depth if spec.depth is None else spec.depth
    lift = (0.10 + 0.14 * depth) * body.height / 1.75
    first = int(ctx.rng.integers(2))
    starts = START_S + np.r_[0.0, np.cumsum(durations[:-1])]
    plants: list[list[Plant]] = [[], []]
    for side in (LEFT, RIGHT):
        lateral = (0.5 if side == LEFT else -0.5) * body.hip_spacing
        yaw = place.heading + (TOE_OUT if side == LEFT else -TOE_OUT)
        plants[side].append(Plant(0.0, 0.0, place.xy(0.0, lateral), yaw))
    for k in range(steps):
        side = (first + k) % 2
        before = plants[side][-1]
        plants[side][-1] = _with_release(before, starts[k], -0.2, 0.12 * durations[k])
        height = lift * float(np.clip(ctx.jitter(0.05), 0.85, 1.15))
        plants[side].append(
            Plant(
                starts[k] + 0.7 * durations[k],
                np.inf,
                before.xy,
                before.yaw,
                strike=TOE,
                strike_pitch=-0.15,
                strike_s=0.12 * durations[k],
                lift_before=height,
                swing_pitch=-0.2,
            )
        )
    end_s = starts[-1] + 0.7 * durations[-1] + SETTLE_S
    t = ctx.times(end_s)
    feet = (foot_track(body, LEFT, plants[LEFT], t), foot_track(body, RIGHT, plants[RIGHT], t))
    p = _drive(ctx, place, t, feet, round(step_s * ctx.rate_hz))
    rise = feet[RIGHT].ankle[:, 2] - feet[LEFT].ankle[:, 2]
    swing = 0.3 * np.clip(rise / lift, -1.0, 1.0)
    flex = np.stack([swing, -swing], axis=1)
    p = p.replace(shoulder_flex=flex, elbow_flex=ELBOW_REST + 0.8 * np.maximum(flex, 0.0))
    action = np.full(len(t), ACTIONS.index("in_place_walking"), dtype=np.int64)
    ground = np.stack([f.ground_z for f in feet], axis=1)
    return Segment(finalize(body, p), action, place, ground)


def side_walking(ctx: Context, spec: ActionSpec, place: Place) -> Segment:
    """Side steps: the leading foot steps out (feet apart), the other closes (together)."""
    body, subject = ctx.body, ctx.subject
    step_s = 60.0 / (0.75 * subject.cadence_spm * spec.tempo)
    reps = steps_for(spec, 2 * step_s, least=1)
    width = spec.step_length_m or 0.25 * body.height
    sign = 1.0 if spec.direction == "left" else -1.0
    lead = LEFT if sign > 0 else RIGHT
    durations = ctx.rep_durations(step_s, 1.0, 2 * reps)
    starts = START_S + np.r_[0.0, np.cumsum(durations[:-1])]
    plants: list[list[Plant]] = [[], []]
    lateral = [0.5 * body.hip_spacing, -0.5 * body.hip_spacing]
    for side in (LEFT, RIGHT):
        yaw = place.heading + (TOE_OUT if side == LEFT else -TOE_OUT)
        plants[side].append(Plant(0.0, 0.0, place.xy(0.0, lateral[side]), yaw))
    travelled = 0.0
    for k in range(2 * reps):
        side = lead if k % 2 == 0 else 1 - lead
        if k % 2 == 0:
            travelled += sign * width * float(np.clip(ctx.jitter(0.04), 0.9, 1.1))
        before = plants[side][-1]
        plants[side][-1] = _with_release(before, starts[k], 0.0, 0.0)
        plants[side].append(
            Plant(
                starts[k] + 0.6 * durations[k],
                np.inf,
                place.xy(0.0, lateral[side] + travelled),
                before.yaw,
                strike=TOE,
                strike_pitch=-0.1,
                strike_s=0.15 * durations[k],
                lift_before=0.05,
            )
        )
    end_s = starts[-1] + 0.6 * durations[-1] + SETTLE_S
    t = ctx.times(end_s)
    feet = (foot_track(body, LEFT, plants[LEFT], t), foot_track(body, RIGHT, plants[RIGHT], t))
    p = _drive(ctx, place, t, feet, round(step_s * ctx.rate_hz))
    envelope = ease(t / START_S) * ease((end_s - t) / SETTLE_S)
    p = p.replace(shoulder_flex=p.shoulder_flex + 0.1 * envelope[:, None])
    action = np.full(len(t), ACTIONS.index("side_walking"), dtype=np.int64)
    end = Place(*place.xy(0.0, travelled), place.heading, place.floor_z)
    ground = np.stack([f.ground_z for f in feet], axis=1)
    return Segment(finalize(body, p), action, end, ground)
