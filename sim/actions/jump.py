"""Jumping in place: countermovement, push-off, flight, landing, rebound.

A set of jumps is one continuous rhythm, as in repeated countermovement
jumps: stand, sink, push off (heels rise, the feet roll onto the toes),
fly ballistically with both feet off the floor, land on the toes, absorb with
the knees and, from that same crouch, push off again. After the last landing
the person rises to stand.

Labels: the progress indicator of a jump is the negative mid-hip height, so
one repetition runs crouch -> top of the flight -> crouch. The action is
labelled from the first crouch to the last; the sink before and the rise
after are transition (NO_ACTION), so the labeller counts exactly ``reps``.
"""

from __future__ import annotations

import numpy as np
from scotti.models.contract import ACTIONS, NO_ACTION
from scotti.sim.actions.base import ActionSpec, Context, Place, Segment, finalize, neutral
from scotti.sim.actions.curves import box_smooth, ease, hermite
from scotti.sim.skeleton import LEFT, RIGHT, ankle_on_pivot, foot_points

G = 9.81
START_S = 0.3
SINK_S = 0.55  # stand -> first crouch
PUSH_S = 0.28  # crouch -> take-off
ABSORB_S = 0.26  # touch-down -> crouch
RISE_S = 0.7  # last crouch -> stand
TAKEOFF_PITCH = 0.65  # radians the feet point down at take-off and landing
HEEL_RISE_SHARE = 0.55  # the heels rise over the last part of the push
REACH = 0.985  # share of leg length at take-off (nearly straight)


def jump(ctx: Context, spec: ActionSpec, place: Place) -> Segment:
    body, subject = ctx.body, ctx.subject
    reps = spec.reps or max(1, round((spec.duration_s or 0.0) * spec.tempo / 1.0))
    depth = subject.depth if spec.depth is None else spec.depth
    base = neutral(body, place, 1)
    stand_z = float(base.pelvis[0, 2])
    # Take-off height: legs nearly straight above feet standing on their toes.
    toe = foot_points(body, LEFT, base.ankle[:, LEFT], base.foot_yaw[:, LEFT], np.zeros(1))[:, 1]
    on_toes = ankle_on_pivot(body, LEFT, toe, 1, base.foot_yaw[:, LEFT], np.array([-TAKEOFF_PITCH]))
    takeoff_z = float(on_toes[0, 2]) + REACH * body.leg
    crouch = (0.10 + 0.12 * depth) * body.height / 1.75
    flights = (0.30 + 0.15 * depth) * np.clip(ctx.jitter(0.06, reps), 0.8, 1.2) / spec.tempo**0.5
    # Keyframes of the hip height (with velocities) and of the heel lift share.
    knot_t = [0.0, START_S, START_S + SINK_S]
    knot_z = [stand_z, stand_z, stand_z - crouch]
    knot_v = [0.0, 0.0, 0.0]
    flight_windows: list[tuple[float, float]] = []
    t0 = START_S + SINK_S
    first_crouch = t0
    for k, flight in enumerate(flights):
        v0 = 0.5 * G * flight
        up = t0 + PUSH_S / spec.tempo
        down = up + flight
        flight_windows.append((up, down))
        knot_t += [up, down]
        knot_z += [takeoff_z, takeoff_z]
        knot_v += [v0, -v0]
        t0 = down + ABSORB_S / spec.tempo
        sink = crouch * float(np.clip(ctx.jitter(0.05), 0.85, 1.15)) if k < reps - 1 else crouch
        knot_t.append(t0)
        knot_z.append(stand_z - sink)
        knot_v.append(0.0)
    last_crouch = t0
    end_s = t0 + RISE_S + 0.2
    knot_t += [t0 + RISE_S, end_s]
    knot_z += [stand_z, stand_z]
    knot_v += [0.0, 0.0]
    t = ctx.times(end_s)
    hip_z = hermite(t, knot_t, knot_z, knot_v)
    toes_share = np.zeros(len(t))  # 0 flat .. 1 on the toes at TAKEOFF_PITCH
    flying = np.zeros(len(t), dtype=bool)
    for up, down in flight_windows:
        air = (t > up) & (t < down)
        flying |= air
        tau = t[air] - up
        flight = down - up
        hip_z[air] = takeoff_z + 0.5 * G * flight * tau - 0.5 * G * tau**2
        push = PUSH_S / spec.tempo
        rising = (t >= up - HEEL_RISE_SHARE * push) & (t <= up)
        toes_share[rising] = ease(
            (t[rising] - (up - HEEL_RISE_SHARE * push)) / (HEEL_RISE_SHARE * push)
        )
        landing = (t >= down) & (t <= down + 0.5 * ABSORB_S / spec.tempo)
        toes_share[landing] = 1.0 - ease((t[landing] - down) / (0.5 * ABSORB_S / spec.tempo))
        toes_share[air] = 1.0
    p = neutral(body, place, len(t))
    pitch = -TAKEOFF_PITCH * toes_share
    ankle = p.ankle.copy()
    for side in (LEFT, RIGHT):
        yaw = p.foot_yaw[:, side]
        toes = foot_points(body, side, p.ankle[:, side], yaw, np.zeros(len(t)))[:, 1]
        ankle[:, side] = ankle_on_pivot(body, side, toes, 1, yaw, pitch)
        # In the air the feet hang below the hips, as at take-off.
        ankle[flying, side, 2] = hip_z[flying] - REACH * body.leg
    crouched = np.clip((stand_z - hip_z) / crouch, 0.0, 1.0)
    arms = np.where(flying, 1.2, -0.6 * crouched)
    arms = box_smooth(arms, max(1, round(0.25 * ctx.rate_hz)))
    p = p.replace(
        pelvis=np.c_[p.pelvis[:, :2], hip_z],
        ankle=ankle,
        foot_pitch=np.stack([pitch, pitch], axis=1),
        lean=0.35 * crouched,
        shoulder_flex=np.stack([arms, arms], axis=1),
        elbow_flex=p.elbow_flex + 0.3 * np.maximum(arms, 0.0)[:, None],
    )
    action = np.full(len(t), NO_ACTION, dtype=np.int64)
    action[(t >= first_crouch) & (t <= last_crouch)] = ACTIONS.index("jump")
    return Segment(finalize(body, p), action, place, np.zeros((len(t), 2)))
