"""Walking, backward walking, side walking and walking in place.

For these four a repetition is one step (one foot's swing), as the progress
labeller cuts them: by heel distance (walking, side walking), heel height
(in place: cut with both feet down) or heel displacement (backward).
Walking is built from a gait cycle with stance 60 %, double support
2 x 10 %, the person's own touch-down (heel strike, flat foot or toes first,
``Traits.strike``) -> flat foot -> heel rise -> toe off (rolling over the
toes by 0.6 rad, scaled by the person's ``push_off``: a shuffling walker's
heel barely rises); the pelvis follows the standing feet and its height an
inverted pendulum (``pendulum.py``). Steps land the person's step width
apart, turned out by their toe-out; the path may curve and turn (a lab
walkway: straight, turn round, back) and the speed may drift, the heading
following the path. Backward walking has its own gait in ``backward.py``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scotti.models.contract import ACTIONS, NO_ACTION
from scotti.sim.actions.base import (
    ELBOW_REST,
    ActionSpec,
    Context,
    Place,
    Segment,
    finalize,
    foot_yaw,
    neutral,
    stance_lateral,
)
from scotti.sim.actions.curves import ease, hermite
from scotti.sim.actions.footsteps import FLAT, HEEL, TOE, FootTrack, Plant, foot_track, support_path
from scotti.sim.actions.paths import (
    SHARP_TURN_RAD,
    headings,
    keep_clear,
    knot_velocity,
    speed_factors,
)
from scotti.sim.actions.pendulum import pendulum_height, steer_com_to_pendulum
from scotti.sim.skeleton import LEFT, RIGHT, Array, PoseParams, axes

STANCE = 0.6  # share of the gait cycle a foot stands (Winter; Perry)
# Slow walkers stand longer in each cycle: about 0.6 at comfortable speed,
# two thirds near 0.6 m/s (double support 20 % -> 33 %; Kirtley et al. 1985,
# Winter 1991, gaitpdb's slowest walker here: 32 % at 79 steps/min). Our
# stance share rises linearly below SLOW_CADENCE to STANCE_SLOWEST at
# SLOWEST_CADENCE; at or above SLOW_CADENCE (every walker the typical
# population draws) it is STANCE.
SLOW_CADENCE = 95.0
SLOWEST_CADENCE = 55.0
STANCE_SLOWEST = 0.68
SETTLE_S = 0.5  # after the closing step, before the segment ends
START_S = 0.3  # weight shift before the first swing
LEAD_AT_STRIKE = [0.1, 0.2]
# Gait initiation: the first step from standing is shorter than the steady ones.
FIRST_STEP = 0.75


def stance_share(cadence_spm: float) -> float:
    """Share of the gait cycle a foot stands at this cadence (steps per minute)."""
    slow = (SLOW_CADENCE - cadence_spm) / (SLOW_CADENCE - SLOWEST_CADENCE)
    return STANCE + (STANCE_SLOWEST - STANCE) * float(np.clip(slow, 0.0, 1.0))


def steps_for(spec: ActionSpec, step_s: float, least: int = 2) -> int:
    """Steps asked for: ``reps``, or as many as fit ``duration_s``."""
    if spec.reps is not None:
        return max(least, spec.reps)
    return max(least, round((spec.duration_s or 0.0) / step_s))


def walking(ctx: Context, spec: ActionSpec, place: Place) -> Segment:
    traits = ctx.subject.traits
    return _walk(
        ctx, spec, place, ACTIONS.index("walking"), 1.0, 1.0, traits.strike_pitch_rad,
        -0.6 * traits.push_off, 0.04,
        strike=traits.strike, turns=True,
    )  # fmt: skip


def transition_walk(
    ctx: Context, place: Place, steps: int, turn_rad: float, length_scale: float
) -> Segment:
    """Walking to the next spot or turning round: a short walk labelled NO_ACTION."""
    spec = ActionSpec("walking", reps=max(2, steps), turn_rad=turn_rad)
    traits = ctx.subject.traits
    return _walk(
        ctx, spec, place, NO_ACTION, length_scale, 0.9, traits.strike_pitch_rad,
        -0.5 * traits.push_off, 0.02,
        strike=traits.strike, turns=True,
    )  # fmt: skip


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
    *,
    strike: str = "heel",
    turns: bool = False,
) -> Segment:
    """Steps along a path that may curve and turn (``turns``), at a speed that may drift.

    Each step lands one step length along the path from the other foot,
    ``step_width`` apart across it and turned out by the person's toe-out;
    the last two steps go back to the stance width so that the walk ends in
    the neutral stand. The pelvis follows the path (forwards) and sways over
    the standing foot (across); the heading turns with the path.
    """
    body, subject = ctx.body, ctx.subject
    traits = subject.traits
    step_s = 60.0 / (subject.cadence_spm * cadence_scale * spec.tempo)
    steps = steps_for(spec, step_s)
    # The walker's own pace sets the stance share (a transition's quicker or
    # slower steps, cadence_scale, do not).
    stance = stance_share(subject.cadence_spm * spec.tempo)
    length = (spec.step_length_m or subject.step_length_m) * length_scale
    speed = speed_factors(ctx, steps, traits.speed_variability) if spec.vary else np.ones(steps)
    durations = step_s * np.clip(ctx.jitter(traits.stride_cv, steps), 0.85, 1.15) / speed**0.5
    lengths = length * np.clip(ctx.jitter(0.03, steps), 0.9, 1.1) * speed**0.5
    lengths[0] *= FIRST_STEP
    first = int(ctx.rng.integers(2))  # which foot swings first
    swinging = [(first + k) % 2 for k in range(steps)]
    lengths *= np.array([1.0 + (0.5 if s == RIGHT else -0.5) * subject.asymmetry for s in swinging])
    turn, scale = headings(ctx, spec, lengths, turns)
    lengths *= scale
    durations *= np.where(scale < 1.0, 1.1, 1.0)
    toe_off = START_S + np.r_[0.0, np.cumsum(durations[:-1])]
    heel_strike = toe_off + (1.0 - stance) * 2 * durations
    # Where each step lands on the path and which way the body then faces;
    # the last step closes beside the one before.
    heading = place.heading + np.cumsum(turn)
    centre = np.zeros((steps, 2))
    at, facing = np.array([place.x, place.y]), place.heading
    for k in range(steps):
        if k < steps - 1:
            mean = 0.5 * (facing + heading[k])
            at = at + lengths[k] * np.array([np.cos(mean), np.sin(mean)])
            facing = heading[k]
        centre[k] = at
    heading[-1] = heading[-2] if steps > 1 else heading[-1]
    width = traits.step_width_m
    plants: list[list[Plant]] = [[], []]
    for side in (LEFT, RIGHT):
        home = place.xy(0.0, stance_lateral(body, side))
        plants[side].append(Plant(0.0, 0.0, home, foot_yaw(body, side, place.heading)))
    pivot = HEEL if strike_pitch >= 0 else TOE
    strike_share = {"heel": 0.24, "midfoot": 0.08, "forefoot": 0.15}[strike]
    for k, side in enumerate(swinging):
        last = k == steps - 1
        # The last two steps, and steps that turn sharply, stand at stance width.
        wide = k >= steps - 2 or abs(turn[k]) > SHARP_TURN_RAD
        across = stance_lateral(body, side) if wide else (0.5 if side == LEFT else -0.5) * width
        _, lft = axes(heading[k])
        xy = centre[k] + across * lft[:2]
        before = plants[side][-1]
        release_s = min(0.5 * durations[k], 0.8 * (toe_off[k] - before.t_on))
        plants[side][-1] = _with_release(before, toe_off[k], release_pitch, release_s)
        plants[side].append(
            Plant(
                heel_strike[k],
                np.inf,
                (float(xy[0]), float(xy[1])),
                foot_yaw(body, side, float(heading[k])),
                strike=pivot,
                strike_pitch=strike_pitch * (0.5 if last else 1.0),
                strike_s=strike_share * durations[k],
                lift_before=0.05,
                lift_power=1.0,
            )
        )
    end_s = heel_strike[-1] + SETTLE_S
    t = ctx.times(end_s)
    # Along the path the pelvis is half-way between the feet at each heel
    # strike; across it it sways over the stance foot (``support_path``).
    start = np.array([[place.x, place.y]])
    middles = 0.5 * (centre[:-1] + np.r_[start, centre[:-2]])
    mid_heading = 0.5 * (heading[:-1] + np.r_[place.heading, heading[:-2]])
    knot_t = np.r_[0.0, heel_strike[:-1], end_s - SETTLE_S, end_s]
    knot_xy = np.r_[start, middles, centre[-1:], centre[-1:]]
    knot_h = np.r_[place.heading, mid_heading, heading[-1], heading[-1]]
    path = hermite(t, knot_t, knot_xy, knot_velocity(knot_xy, knot_t))
    facing_t = hermite(t, knot_t, knot_h, knot_velocity(knot_h, knot_t))
    _, left_t = axes(facing_t)
    tracks = [foot_track(body, side, plants[side], t) for side in (LEFT, RIGHT)]
    feet = keep_clear(tracks[LEFT], tracks[RIGHT], left_t[:, :2])
    envelope = ease(t / START_S) * ease((end_s - t) / SETTLE_S)
    p = _drive(ctx, place, t, feet, round(step_s * ctx.rate_hz))
    half = 0.5 * body.stance_width
    sway = np.clip(np.sum((p.pelvis[:, :2] - path) * left_t[:, :2], axis=1), -half, half)
    pelvis = p.pelvis.copy()
    pelvis[:, :2] = path + sway[:, None] * left_t[:, :2]
    p = p.replace(lean=lean * envelope, pelvis=pelvis, heading=facing_t)
    ground = np.stack([f.ground_z for f in feet], axis=1)
    p = p.replace(pelvis=pendulum_height(body, p, t, ground, end_s))
    p = _arm_swing(p, feet, facing_t, length, 0.35)
    p = steer_com_to_pendulum(body, p, round(step_s * ctx.rate_hz), envelope)
    end = Place(float(centre[-1, 0]), float(centre[-1, 1]), float(heading[-1]), place.floor_z)
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
    p: PoseParams, feet: tuple[FootTrack, FootTrack], heading: Array, span: float, amp: float
) -> PoseParams:
    """Each arm swings with the opposite leg: forwards when that foot is ahead."""
    f, _ = axes(heading)  # (N, 3)
    ahead = np.sum((feet[RIGHT].ankle - feet[LEFT].ankle) * f, axis=1)  # right ahead, metres
    swing = amp * np.clip(ahead / max(span, 1e-6), -1.0, 1.0)
    flex = np.stack([swing, -swing], axis=1)
    elbow = ELBOW_REST + 0.4 * np.maximum(flex, 0.0)
    return p.replace(shoulder_flex=flex, elbow_flex=elbow)


def in_place_walking(ctx: Context, spec: ActionSpec, place: Place) -> Segment:
    """Marching on the spot: knees lift by turns, the feet land where they were."""
    body, subject = ctx.body, ctx.subject
    step_s = 60.0 / (0.9 * subject.cadence_spm * spec.tempo)
    steps = steps_for(spec, step_s, least=1)
    speed = speed_factors(ctx, steps, subject.traits.speed_variability) if spec.vary else 1.0
    durations = ctx.rep_durations(step_s, 1.0, steps) / speed
    depth = subject.depth if spec.depth is None else spec.depth
    lift = (0.10 + 0.14 * depth) * body.height / 1.75
    first = int(ctx.rng.integers(2))
    starts = START_S + np.r_[0.0, np.cumsum(durations[:-1])]
    plants: list[list[Plant]] = [[], []]
    for side in (LEFT, RIGHT):
        home = place.xy(0.0, stance_lateral(body, side))
        plants[side].append(Plant(0.0, 0.0, home, foot_yaw(body, side, place.heading)))
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
    if spec.vary:
        durations /= np.repeat(speed_factors(ctx, reps, subject.traits.speed_variability), 2)
    starts = START_S + np.r_[0.0, np.cumsum(durations[:-1])]
    plants: list[list[Plant]] = [[], []]
    lateral = [stance_lateral(body, LEFT), stance_lateral(body, RIGHT)]
    for side in (LEFT, RIGHT):
        yaw = foot_yaw(body, side, place.heading)
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
