"""Step-ups onto a step in front of the person, and back down.

One repetition: the leading foot steps up onto the step, the other follows
beside it (standing on the step), the leading foot steps back down to where
it stood, the other follows. Leading legs alternate. Feet on the step stand
at the step's height, which ``Segment.ground_z`` reports as the surface under
them; the pelvis follows the standing feet sideways and forwards.

Its height is drawn from the force it takes (``rise_share``): a quick push
as the leading leg lifts the body and a long ease onto the step, which loads
the leading leg with 1.3-1.5 body weights for a 0.2 m step (stair ascent:
from a little above body weight on shallow stairs up to 1.6 on steep ones,
Stacoff et al. 2005, "Ground reaction forces on stairs: effects of stair
inclination and age", Gait & Posture 21:24-38), and the mirror image on the
way down, braking as the leading foot lands back on the floor.
"""

from __future__ import annotations

from dataclasses import replace

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
from scotti.sim.actions.curves import bump
from scotti.sim.actions.footsteps import FLAT, TOE, Plant, foot_track, support_path
from scotti.sim.skeleton import LEFT, RIGHT, Array

START_S = 0.3
STEP_UP_S = 4.2  # one repetition at tempo 1
STEP_AHEAD = 0.20  # x height: ankle on the step ahead of the ankle on the floor
SETTLE_S = 0.4
# Phase of each swing within a repetition: (start, end) as shares of its duration.
SWINGS = ((0.0, 0.17), (0.22, 0.39), (0.52, 0.69), (0.74, 0.91))
# When the COM rises onto the step and comes back down (shares of a repetition):
# up while the leading leg lifts the body and the trailing one swings up,
# down while the leading foot reaches back to the floor.
RISE = (0.21, 0.39)
DROP = (0.47, 0.69)


def rise_share(s: Array) -> Array:
    """0 -> 1 over s = 0..1 with speed ~ s^2 (1-s)^4: a quick push, a long ease onto the step.

    The regularised incomplete beta function I_s(3, 5); its acceleration
    peaks at 11 h / T^2 early in the rise (about 1.3-1.4 body weights for a
    0.2 m step in 0.8 s) and brakes at 6.5 h / T^2.
    """
    x = np.clip(s, 0.0, 1.0)
    return np.asarray(
        105.0 * (x**3 / 3.0 - x**4 + 1.2 * x**5 - 2.0 * x**6 / 3.0 + x**7 / 7.0),
        dtype=np.float64,
    )


def step_up(ctx: Context, spec: ActionSpec, place: Place) -> Segment:
    body = ctx.body
    reps = spec.reps or max(1, round((spec.duration_s or 0.0) * spec.tempo / STEP_UP_S))
    durations = ctx.rep_durations(STEP_UP_S, spec.tempo, reps)
    height = spec.step_height_m
    ahead = STEP_AHEAD * body.height
    lateral = [stance_lateral(body, LEFT), stance_lateral(body, RIGHT)]
    yaws = [foot_yaw(body, LEFT, place.heading), foot_yaw(body, RIGHT, place.heading)]
    home = [Plant(0.0, 0.0, place.xy(0.0, lateral[s]), yaws[s]) for s in (LEFT, RIGHT)]
    plants: list[list[Plant]] = [[home[LEFT]], [home[RIGHT]]]
    first = int(ctx.rng.integers(2))
    t0 = START_S
    for k, d in enumerate(durations):
        lead = (first + k) % 2
        order = (lead, 1 - lead, lead, 1 - lead)
        for i, (side, (a, b)) in enumerate(zip(order, SWINGS, strict=True)):
            on_step = i < 2
            before = plants[side][-1]
            # Leaving the floor for the step the foot rolls onto its toes.
            release, pitch = (TOE, -0.45) if i == 1 else (FLAT, 0.0)
            plants[side][-1] = replace(
                before,
                t_off=t0 + a * d,
                release=release,
                release_pitch=pitch,
                release_s=0.06 * d if i == 1 else 0.0,
            )
            target = place.xy(ahead, lateral[side]) if on_step else home[side].xy
            plants[side].append(
                Plant(
                    t0 + b * d,
                    np.inf,
                    target,
                    yaws[side],
                    floor_z=height if on_step else 0.0,
                    strike=FLAT if on_step else TOE,
                    strike_pitch=0.0 if on_step else -0.2,
                    strike_s=0.0 if on_step else 0.08 * d,
                    lift_before=0.06,
                )
            )
        t0 += d
    end_s = t0 + SETTLE_S
    t = ctx.times(end_s)
    feet = (foot_track(body, LEFT, plants[LEFT], t), foot_track(body, RIGHT, plants[RIGHT], t))
    p = neutral(body, place, len(t))
    # Lean into each step up.
    lean = np.zeros(len(t))
    t0 = START_S
    for d in durations:
        lean += 0.15 * bump((t - t0) / (0.45 * d))
        t0 += d
    p = p.replace(
        pelvis=support_path(body, feet, max(1, round(0.5 * ctx.rate_hz))),
        ankle=np.stack([feet[LEFT].ankle, feet[RIGHT].ankle], axis=1),
        foot_yaw=np.stack([feet[LEFT].yaw, feet[RIGHT].yaw], axis=1),
        foot_pitch=np.stack([feet[LEFT].pitch, feet[RIGHT].pitch], axis=1),
        lean=lean,
    )
    # The hips climb and descend the step as drawn (the force it takes is
    # m (g + z''): about 1.3-1.5 body weights on the leading leg going up),
    # not as the smoothed support of the standing feet would have them.
    raised = np.zeros(len(t))
    t0 = START_S
    for d in durations:
        raised += rise_share((t - t0 - RISE[0] * d) / ((RISE[1] - RISE[0]) * d))
        raised -= 1.0 - rise_share(1.0 - (t - t0 - DROP[0] * d) / ((DROP[1] - DROP[0]) * d))
        t0 += d
    pelvis = p.pelvis.copy()
    pelvis[:, 2] = place.floor_z + body.stand_hip_z + height * raised
    p = p.replace(pelvis=pelvis)
    action = np.full(len(t), ACTIONS.index("step_up"), dtype=np.int64)
    ground = np.stack([f.ground_z for f in feet], axis=1)
    return Segment(finalize(body, p), action, place, ground)
