"""Squat and lunge: the hips travel a keyframed path, the legs follow by IK.

Squat: feet stay flat where they stand; the mid-hip goes down and back by an
amount set by ``depth`` (1 = thighs a little past parallel), the trunk leans
forwards and the arms rise in front for balance. Lunge: one foot steps
forwards, the hips sink between the feet with the rear heel up, rise, and
the foot steps back; legs alternate repetition by repetition.

Both follow the person (``Traits``): their own depth and time per
repetition, varied repetition by repetition, slower and shallower as a set
goes on (fatigue), with pauses standing between repetitions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scotti.models.contract import ACTIONS
from scotti.sim.actions.base import (
    ActionSpec,
    Context,
    Place,
    Segment,
    finalize,
    foot_yaw,
    neutral,
    stance_lateral,
)
from scotti.sim.actions.curves import hermite
from scotti.sim.actions.footsteps import FLAT, HEEL, Plant, foot_track
from scotti.sim.skeleton import LEFT, RIGHT, Array, Body, ankle_on_pivot, axes, foot_points

START_S = 0.3
SQUAT_S = 3.0  # one squat at tempo 1 when no person is given (a person has ``squat_rep_s``)
SQUAT_DROP = 0.26  # x height: mid-hip drop at depth 1
SQUAT_BACK = 0.14  # x height: mid-hip moves back at depth 1 (COM and COP towards the heels)
SQUAT_BACK_LEAD = 0.7  # back ~ drop^0.7: the hips lead backwards
SQUAT_ARMS = 0.9  # radians the arms rise in front at depth 1 (more would carry the COM forwards)
LUNGE_S = 3.8  # likewise (``lunge_rep_s``)
LUNGE_LENGTH = 0.45  # x height: step of the lunge
LUNGE_DROP = 0.25  # x height at depth 1
PAUSE_CAP = 3.0  # a pause between repetitions is at most this many times the person's mean


def reps_for(spec: ActionSpec, rep_s: float) -> int:
    """Repetitions asked for: ``reps``, or enough to fill ``duration_s`` (rounded up)."""
    if spec.reps is not None:
        return spec.reps
    return max(1, math.ceil((spec.duration_s or 0.0) * spec.tempo / rep_s - 1e-9))


@dataclass(frozen=True)
class Rep:
    """One repetition of a set: when it starts, how long it takes, how deep it goes."""

    start: float
    duration: float
    depth: float


def schedule(ctx: Context, spec: ActionSpec, rep_s: float, depth: float) -> tuple[list[Rep], float]:
    """Repetitions of a set and when the set ends.

    Each repetition varies around the person's tempo and depth; as the set
    goes on, fatigue slows them down and makes them shallower
    (``Traits.fatigue``); between repetitions the person may pause.
    """
    traits = ctx.subject.traits
    base = traits.depth_variation
    pause_mean = traits.rep_pause_s
    reps = reps_for(spec, rep_s + pause_mean / spec.tempo)
    out: list[Rep] = []
    t0 = START_S
    for k in range(reps):
        slow, shallow = traits.fatigue(t0 - START_S)
        spread = float(np.clip(ctx.jitter(traits.tempo_variation), 0.7, 1.3))
        duration = rep_s * spread * (1.0 + slow) / spec.tempo
        varied = float(np.clip(ctx.jitter(base), 1.0 - 3 * base, 1.0 + 3 * base))
        out.append(Rep(t0, duration, float(np.clip(depth * varied * (1.0 - shallow), 0.0, 1.05))))
        t0 += duration
        if k < reps - 1 and pause_mean > 0:
            t0 += min(ctx.rng.exponential(pause_mean), PAUSE_CAP * pause_mean) / spec.tempo
    return out, t0


def squat(ctx: Context, spec: ActionSpec, place: Place) -> Segment:
    body, traits = ctx.body, ctx.subject.traits
    depth = traits.depth if spec.depth is None else spec.depth
    reps, end_s = schedule(ctx, spec, traits.squat_rep_s, depth)
    # Keyframes of (back, drop, lean, arms) per repetition, zero velocity at each.
    knot_t, knot_y = [0.0, START_S], [np.zeros(4), np.zeros(4)]
    for rep in reps:
        t0, d, depth = rep.start, rep.duration, rep.depth
        bottom = np.array(
            [SQUAT_BACK * depth, SQUAT_DROP * depth, 0.6 * depth, SQUAT_ARMS * depth]
        ) * np.array([body.height, body.height, 1.0, 1.0])
        if t0 > knot_t[-1]:  # a pause at the top
            knot_t.append(t0)
            knot_y.append(np.zeros(4))
        knot_t += [t0 + 0.42 * d, t0 + 0.47 * d, t0 + 0.87 * d, t0 + d]
        knot_y += [bottom, bottom, np.zeros(4), np.zeros(4)]
    t = ctx.times(end_s)
    back, drop, lean, arms = hermite(t, knot_t, np.array(knot_y)).T
    # The hips go back first and the knees forward later, so that the COM (and
    # the COP under it) moves towards the heels from the first centimetre.
    full_drop = SQUAT_DROP * body.height
    back = SQUAT_BACK * body.height * (np.maximum(drop, 0.0) / full_drop) ** SQUAT_BACK_LEAD
    p = neutral(body, place, len(t))
    f, _ = axes(place.heading)
    pelvis = p.pelvis - back[:, None] * f - drop[:, None] * np.array([0.0, 0.0, 1.0])
    p = p.replace(
        pelvis=pelvis,
        lean=lean,
        shoulder_flex=np.stack([arms, arms], axis=1),
        elbow_flex=p.elbow_flex + 0.2 * arms[:, None],
    )
    action = np.full(len(t), ACTIONS.index("squat"), dtype=np.int64)
    return Segment(finalize(body, p), action, place, np.zeros((len(t), 2)))


def lunge(ctx: Context, spec: ActionSpec, place: Place) -> Segment:
    body, traits = ctx.body, ctx.subject.traits
    depth = traits.lunge_depth if spec.depth is None else spec.depth
    reps, end_s = schedule(ctx, spec, traits.lunge_rep_s, depth)
    length = spec.step_length_m or LUNGE_LENGTH * body.height
    first = int(ctx.rng.integers(2))
    lateral = [stance_lateral(body, LEFT), stance_lateral(body, RIGHT)]
    yaws = [foot_yaw(body, LEFT, place.heading), foot_yaw(body, RIGHT, place.heading)]
    plants: list[list[Plant]] = [
        [Plant(0.0, 0.0, place.xy(0.0, lateral[s]), yaws[s])] for s in (LEFT, RIGHT)
    ]
    # Keyframes of (forward, drop, rear-heel lift) and which foot is behind.
    knot_t, knot_y = [0.0, START_S], [np.zeros(3), np.zeros(3)]
    rear_windows: list[tuple[float, float, int]] = []
    for k, rep in enumerate(reps):
        t0, d, depth = rep.start, rep.duration, rep.depth
        front = (first + k) % 2
        side_asym = 1.0 + (0.5 if front == RIGHT else -0.5) * ctx.subject.asymmetry
        step = length * side_asym
        out_on, back_off, back_on = t0 + 0.2 * d, t0 + 0.75 * d, t0 + 0.93 * d
        home = plants[front][-1]
        plants[front][-1] = _until(home, t0)
        plants[front].append(
            Plant(out_on, back_off, place.xy(step, lateral[front]), yaws[front], 0.0,
                  HEEL, 0.25, 0.05 * d, lift_before=0.06)
        )  # fmt: skip
        plants[front].append(Plant(back_on, np.inf, home.xy, home.yaw, lift_before=0.06))
        drop = LUNGE_DROP * depth * side_asym * body.height
        if t0 > knot_t[-1]:  # a pause standing between repetitions
            knot_t.append(t0)
            knot_y.append(np.zeros(3))
        knot_t += [out_on, t0 + 0.45 * d, t0 + 0.5 * d, back_off, back_on, t0 + d]
        knot_y += [
            np.array([0.3 * step, 0.02, 0.4]),
            np.array([0.45 * step, drop, 0.9]),
            np.array([0.45 * step, drop, 0.9]),
            np.array([0.3 * step, 0.02, 0.4]),
            np.zeros(3),
            np.zeros(3),
        ]
        rear_windows.append((t0, t0 + d, 1 - front))
    t = ctx.times(end_s)
    forward, drop, heel = hermite(t, knot_t, np.array(knot_y)).T
    feet = [foot_track(body, s, plants[s], t) for s in (LEFT, RIGHT)]
    ankle = np.stack([feet[LEFT].ankle, feet[RIGHT].ankle], axis=1)
    pitch = np.stack([feet[LEFT].pitch, feet[RIGHT].pitch], axis=1)
    for start, end, side in rear_windows:
        on = (t >= start) & (t < end)
        ankle[on, side], pitch[on, side] = _heel_up(
            body, side, ankle[on, side], yaws[side], heel[on]
        )
    p = neutral(body, place, len(t))
    f, _ = axes(place.heading)
    p = p.replace(
        pelvis=p.pelvis + forward[:, None] * f - drop[:, None] * np.array([0.0, 0.0, 1.0]),
        ankle=ankle,
        foot_pitch=pitch,
        foot_yaw=np.stack([feet[LEFT].yaw, feet[RIGHT].yaw], axis=1),
        lean=0.08 * heel,
        shoulder_flex=np.repeat(0.12 * heel[:, None], 2, axis=1),
    )
    action = np.full(len(t), ACTIONS.index("lunge"), dtype=np.int64)
    return Segment(finalize(body, p), action, place, np.zeros((len(t), 2)))


def _until(plant: Plant, t_off: float) -> Plant:
    return replace(plant, t_off=t_off, release=FLAT)


def _heel_up(body: Body, side: int, ankle: Array, yaw: float, lift: Array) -> tuple[Array, Array]:
    """Raise the heel of a flat foot by turning it about its big toe (``lift`` radians)."""
    n = len(ankle)
    yaws = np.full(n, yaw)
    toe = foot_points(body, side, ankle, yaws, np.zeros(n))[:, 1]
    return ankle_on_pivot(body, side, toe, 1, yaws, -lift), -lift
