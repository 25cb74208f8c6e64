"""Backward walking: its own gait, not forward walking played in reverse.

Walking backwards people take shorter steps at a lower cadence, stand
longer (more double support) and reach back with the swinging foot, which
lands on the forefoot first; the heel then lowers and, at the end of the
stance, the foot (now in front of the body) rolls back onto its heel, the
toes lifting, and leaves heel last (Thorstensson 1986, "How is the normal
locomotor program modified to produce backward walking?", Exp Brain Res
61:664-668; Grasso, Bianchi and Lacquaniti 1998, "Motor patterns for human
gait: backward versus forward locomotion", J Neurophysiol 80:1868-1885).
The centre of pressure thus travels toes -> heel in every stance. Played
in reverse, forward walking had the right footprints but the wrong forces:
a deceleration where there is an acceleration, and the heel-strike
transient at the end of the stance.

The pelvis height comes from the same inverted-pendulum force profile as
forward walking (:mod:`scotti.sim.actions.pendulum`).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Final

import numpy as np
from scotti.models.contract import ACTIONS
from scotti.sim.actions.base import (
    ActionSpec,
    Context,
    Place,
    Segment,
    finalize,
    foot_yaw,
    stance_lateral,
)
from scotti.sim.actions.curves import ease, hermite
from scotti.sim.actions.footsteps import HEEL, TOE, Plant, foot_track
from scotti.sim.actions.gait import SETTLE_S, START_S, steps_for
from scotti.sim.actions.gait import _arm_swing as arm_swing
from scotti.sim.actions.gait import _drive as drive
from scotti.sim.actions.pendulum import pendulum_height, steer_com_to_pendulum
from scotti.sim.skeleton import LEFT, RIGHT, axes

STANCE: Final = 0.65  # share of the cycle a foot stands (forwards 0.60)
LENGTH_SCALE: Final = 0.70  # step length against forwards
CADENCE_SCALE: Final = 0.85  # cadence against forwards
STRIKE_PITCH: Final = -0.25  # radians, heel up as the forefoot lands
RELEASE_PITCH: Final = 0.35  # radians, toes up as the foot rolls back onto the heel
LEAN: Final = -0.03  # the trunk leans slightly back, into the travel


def backward_walking(ctx: Context, spec: ActionSpec, place: Place) -> Segment:
    body, subject = ctx.body, ctx.subject
    step_s = 60.0 / (subject.cadence_spm * CADENCE_SCALE * spec.tempo)
    steps = steps_for(spec, step_s)
    length = (spec.step_length_m or subject.step_length_m) * LENGTH_SCALE
    durations = ctx.rep_durations(step_s, 1.0, steps)
    lengths = length * np.clip(ctx.jitter(0.03, steps), 0.9, 1.1)
    first = int(ctx.rng.integers(2))
    swinging = [(first + k) % 2 for k in range(steps)]
    lengths *= np.array([1.0 + (0.5 if s == RIGHT else -0.5) * subject.asymmetry for s in swinging])
    lift_off = START_S + np.r_[0.0, np.cumsum(durations[:-1])]
    toe_strike = lift_off + (1.0 - STANCE) * 2 * durations
    # How far behind the start each step's foot lands; the last closes beside.
    behind = np.r_[np.cumsum(lengths[:-1]), 0.0]
    behind[-1] = behind[-2] if steps > 1 else 0.0
    lateral = [stance_lateral(body, LEFT), stance_lateral(body, RIGHT)]
    yaws = [foot_yaw(body, LEFT, place.heading), foot_yaw(body, RIGHT, place.heading)]
    plants: list[list[Plant]] = [
        [Plant(0.0, 0.0, place.xy(0.0, lateral[s]), yaws[s])] for s in (LEFT, RIGHT)
    ]
    for k, side in enumerate(swinging):
        last = k == steps - 1
        before = plants[side][-1]
        release_s = min(0.45 * durations[k], 0.8 * (lift_off[k] - before.t_on))
        plants[side][-1] = replace(
            before,
            t_off=lift_off[k],
            release=HEEL if release_s > 0 else before.release,
            release_pitch=RELEASE_PITCH,
            release_s=max(release_s, 0.0),
        )
        plants[side].append(
            Plant(
                toe_strike[k],
                np.inf,
                place.xy(-behind[k], lateral[side]),
                yaws[side],
                strike=TOE,
                strike_pitch=STRIKE_PITCH * (0.5 if last else 1.0),
                strike_s=0.22 * durations[k],
                lift_before=0.045,
                lift_power=1.0,
            )
        )
    end_s = toe_strike[-1] + SETTLE_S
    t = ctx.times(end_s)
    feet = (foot_track(body, LEFT, plants[LEFT], t), foot_track(body, RIGHT, plants[RIGHT], t))
    p = drive(ctx, place, t, feet, round(step_s * ctx.rate_hz))
    # Along the travel the pelvis is half-way between the feet at each strike.
    f, _ = axes(place.heading)
    middles = 0.5 * (behind[:-1] + np.r_[0.0, behind[:-2]])
    knot_t = np.r_[0.0, toe_strike[:-1], end_s - SETTLE_S, end_s]
    knot_u = -np.r_[0.0, middles, behind[-1], behind[-1]]
    knot_v = np.gradient(knot_u, knot_t)
    knot_v[[0, -2, -1]] = 0.0
    along = hermite(t, knot_t, knot_u, knot_v)
    now = (p.pelvis[:, :2] - np.array([place.x, place.y])) @ f[:2]
    pelvis = p.pelvis.copy()
    pelvis[:, :2] += (along - now)[:, None] * f[:2]
    envelope = ease(t / START_S) * ease((end_s - t) / SETTLE_S)
    p = p.replace(lean=LEAN * envelope, pelvis=pelvis)
    ground = np.stack([foot.ground_z for foot in feet], axis=1)
    p = p.replace(pelvis=pendulum_height(body, p, t, ground, end_s))
    p = arm_swing(p, feet, np.full(len(t), place.heading), length, 0.25)
    p = steer_com_to_pendulum(body, p, round(step_s * ctx.rate_hz), envelope)
    end = Place(*place.xy(-behind[-1], 0.0), place.heading, place.floor_z)
    action = np.full(len(t), ACTIONS.index("backward_walking"), dtype=np.int64)
    return Segment(finalize(body, p), action, end, ground)
