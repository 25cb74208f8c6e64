"""Jumping in place: countermovement, push-off, flight, landing, rebound or pause.

A set of countermovement jumps: stand, sink, push off (heels rise, the feet
roll onto the toes), fly ballistically with both feet off the floor, land on
the toes and absorb with the knees. Some sets are continuous (from the
landing crouch the person pushes off again), others pause: after each
landing the person rises and stands 0.5-2 s before the next sink. After the
last landing the person rises to stand.

The landing is drawn from its force: the hips' downward speed ``v0`` decays
as ``v0 (beta (1-s)^P + (1-beta) (1-s)^2)`` over the absorption, a fast
part (the first ~50 ms stop most of the fall: the landing peak) and a slow
one (the knees give), which ends at the crouch with zero speed and zero
acceleration. With the toe-first impact transient (``scotti.sim.loads``)
the landing peaks at 2.5-4 body weights (countermovement and drop-jump
landings: Bobbert, Huijing and van Ingen Schenau 1987, "Drop jumping. I.",
Med Sci Sports Exerc 19:332-338; McNitt-Gray 1993, "Kinetics of the lower
extremities during drop landings from three heights", J Biomech 26:1037-1046).

People are not symmetric: per subject and per jump one foot hangs a little
lower and lands (and leaves) a few milliseconds earlier, and the body sits a
little over one leg, so the feet share the landing unevenly.

Labels: the progress indicator of a jump is the negative mid-hip height, so
one repetition runs crouch -> top of the flight -> crouch. The action is
labelled from a jump's countermovement crouch to its landing crouch (over a
continuous set: from the first crouch to the last); the sink before, the
rise after and the stand of a pause are NO_ACTION, so every jump counts
once and a pause is the standing it is.
"""

from __future__ import annotations

from typing import Final

import numpy as np
from scotti.models.contract import ACTIONS, NO_ACTION
from scotti.sim.actions.base import ActionSpec, Context, Place, Segment, finalize, neutral
from scotti.sim.actions.com import com_z, steer_com_z, take
from scotti.sim.actions.curves import box_smooth, bump, ease, hermite
from scotti.sim.skeleton import (
    LEFT,
    RIGHT,
    Array,
    Body,
    PoseParams,
    ankle_on_pivot,
    axes,
    foot_points,
)

G: Final = 9.81
START_S: Final = 0.3
SINK_S: Final = 0.55  # stand -> countermovement crouch
PUSH_S: Final = 0.28  # crouch -> take-off
RISE_S: Final = 0.7  # landing crouch -> stand
TAKEOFF_PITCH: Final = 0.65  # radians the feet point down at take-off and landing
HEEL_RISE_SHARE: Final = 0.55  # the heels rise over the last part of the push
HEEL_DOWN_S: Final = 0.12  # after touch-down the heels come down
REACH: Final = 0.985  # share of leg length at take-off (nearly straight)
# Landing: share of the fall stopped by the fast part, and its sharpness.
LAND_FAST: Final = 0.5
LAND_POWER: Final = 10.0
# Landing crouch against the countermovement's (a pause lets the person land
# a little stiffer than they sink).
LAND_CROUCH: Final = 0.8
PAUSED_SETS: Final = 0.5  # share of sets with a stand between jumps
PAUSE_S: Final = (0.5, 2.0)
# Asymmetry: touch-down gap (s) per unit of the subject's asymmetry, its
# spread per jump, and the sideways lean over one leg (m) likewise.
GAP_PER_ASYMMETRY: Final = 0.15
GAP_SPREAD_S: Final = 0.006
LEAN_PER_ASYMMETRY: Final = 0.2
LEAN_SPREAD_M: Final = 0.005


def landing_drop(s: np.ndarray) -> np.ndarray:
    """Share (0..1) of the landing's hip drop done at ``s`` (0..1) of the absorption."""
    q = 1.0 - np.clip(s, 0.0, 1.0)
    fast = LAND_FAST * (1.0 - q ** (LAND_POWER + 1.0)) / (LAND_POWER + 1.0)
    slow = (1.0 - LAND_FAST) * (1.0 - q**3) / 3.0
    return np.asarray((fast + slow) / _landing_scale(), dtype=np.float64)


def _landing_scale() -> float:
    """The drop (in units of v0 * T) the speed profile covers over the whole absorption."""
    return LAND_FAST / (LAND_POWER + 1.0) + (1.0 - LAND_FAST) / 3.0


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
    paused = bool(ctx.rng.random() < PAUSED_SETS)
    pauses = ctx.rng.uniform(*PAUSE_S, size=reps) if paused else np.zeros(reps)
    gaps = subject.asymmetry * GAP_PER_ASYMMETRY + GAP_SPREAD_S * ctx.rng.standard_normal(reps)
    leans = subject.asymmetry * LEAN_PER_ASYMMETRY + LEAN_SPREAD_M * ctx.rng.standard_normal(reps)
    push = PUSH_S / spec.tempo
    # Keyframes of the hip height with velocities; flights and landings are
    # drawn exactly afterwards, the keyframes only join them.
    knot_t = [0.0, START_S, START_S + SINK_S]
    knot_z = [stand_z, stand_z, stand_z - crouch]
    knot_v = [0.0, 0.0, 0.0]
    flight_windows: list[tuple[float, float]] = []
    landings: list[tuple[float, float, float, float]] = []  # (down, end, v0, drop)
    labelled: list[tuple[float, float]] = []
    t0 = START_S + SINK_S
    run_start = t0
    for k, flight in enumerate(flights):
        v0 = 0.5 * G * flight
        up = t0 + push
        down = up + flight
        flight_windows.append((up, down))
        last = k == reps - 1
        sink = crouch * float(np.clip(ctx.jitter(0.05), 0.85, 1.15)) if not last else crouch
        land_crouch = sink * (LAND_CROUCH if (paused or last) else 1.0)
        drop = takeoff_z - (stand_z - land_crouch)
        absorb = drop / (v0 * _landing_scale())
        landings.append((down, down + absorb, v0, drop))
        t0 = down + absorb
        knot_t += [up, down, t0]
        knot_z += [takeoff_z, takeoff_z, stand_z - land_crouch]
        knot_v += [v0, -v0, 0.0]
        if paused and not last:
            labelled.append((run_start, t0))
            knot_t += [t0 + RISE_S, t0 + RISE_S + pauses[k], t0 + RISE_S + pauses[k] + SINK_S]
            knot_z += [stand_z, stand_z, stand_z - sink]
            knot_v += [0.0, 0.0, 0.0]
            t0 = t0 + RISE_S + pauses[k] + SINK_S
            run_start = t0
    labelled.append((run_start, t0))
    end_s = t0 + RISE_S + 0.2
    knot_t += [t0 + RISE_S, end_s]
    knot_z += [stand_z, stand_z]
    knot_v += [0.0, 0.0]
    t = ctx.times(end_s)
    hip_z = hermite(t, knot_t, knot_z, knot_v)
    toes_share = np.zeros(len(t))  # 0 flat .. 1 on the toes at TAKEOFF_PITCH
    flying = np.zeros(len(t), dtype=bool)
    lower = np.zeros((len(t), 2))  # how much lower each foot hangs in the air
    lateral = np.zeros(len(t))
    for k, ((up, down), (_, land_end, v0, drop)) in enumerate(
        zip(flight_windows, landings, strict=True)
    ):
        air = (t > up) & (t < down)
        flying |= air
        tau = t[air] - up
        hip_z[air] = takeoff_z + v0 * tau - 0.5 * G * tau**2
        landing = (t >= down) & (t <= land_end)
        hip_z[landing] = takeoff_z - drop * landing_drop((t[landing] - down) / (land_end - down))
        rising = (t >= up - HEEL_RISE_SHARE * push) & (t <= up)
        toes_share[rising] = ease(
            (t[rising] - (up - HEEL_RISE_SHARE * push)) / (HEEL_RISE_SHARE * push)
        )
        heels_down = (t >= down) & (t <= down + HEEL_DOWN_S)
        toes_share[heels_down] = 1.0 - ease((t[heels_down] - down) / HEEL_DOWN_S)
        toes_share[air] = 1.0
        # The early foot hangs v0 * gap lower: it lands (and leaves) that much sooner.
        early = LEFT if gaps[k] > 0 else RIGHT
        lower[air, early] = v0 * abs(gaps[k])
        lateral += leans[k] * bump((t - (down - 0.4)) / 0.8)
    p = neutral(body, place, len(t))
    pitch = -TAKEOFF_PITCH * toes_share
    ankle = p.ankle.copy()
    for side in (LEFT, RIGHT):
        yaw = p.foot_yaw[:, side]
        toes = foot_points(body, side, p.ankle[:, side], yaw, np.zeros(len(t)))[:, 1]
        ankle[:, side] = ankle_on_pivot(body, side, toes, 1, yaw, pitch)
        # In the air the feet hang below the hips, as at take-off.
        ankle[flying, side, 2] = hip_z[flying] - REACH * body.leg - lower[flying, side]
    crouched = np.clip((stand_z - hip_z) / crouch, 0.0, 1.0)
    arms = np.where(flying, 1.2, -0.6 * crouched)
    arms = box_smooth(arms, max(1, round(0.25 * ctx.rate_hz)))
    _, left = axes(place.heading)
    pelvis = np.c_[p.pelvis[:, :2] + lateral[:, None] * left[:2], hip_z]
    p = p.replace(
        pelvis=pelvis,
        ankle=ankle,
        foot_pitch=np.stack([pitch, pitch], axis=1),
        lean=0.35 * crouched,
        shoulder_flex=np.stack([arms, arms], axis=1),
        elbow_flex=p.elbow_flex + 0.3 * np.maximum(arms, 0.0)[:, None],
    )
    p = _com_follows_hips(body, p, t, flight_windows, [end for _, end, _, _ in landings])
    action = np.full(len(t), NO_ACTION, dtype=np.int64)
    for a, b in labelled:
        action[(t >= a) & (t <= b)] = ACTIONS.index("jump")
    return Segment(finalize(body, p), action, place, np.zeros((len(t), 2)))


def _com_follows_hips(
    body: Body,
    p: PoseParams,
    t: Array,
    flights: list[tuple[float, float]],
    landing_ends: list[float],
) -> PoseParams:
    """Move the hips so that the whole body's COM, not the hips, flies and lands as drawn.

    From take-off to the end of the landing the COM follows the hips' drawn
    path (ballistic, then the landing's speed profile), shifted by the
    COM's offset from the hips at take-off and blended (quintic, zero speed
    and acceleration at both ends) over the landing to its offset at the
    crouch. The arms swinging and the trunk leaning would otherwise bend the
    COM's flight off the parabola and blunt the landing.
    """
    target = np.zeros(len(t))
    window = np.zeros(len(t), dtype=bool)
    hip = p.pelvis[:, 2]
    spans = []
    for (up, _), end in zip(flights, landing_ends, strict=True):
        i_up = int(np.searchsorted(t, up))
        i_end = min(len(t) - 1, int(np.searchsorted(t, end)))
        spans.append((i_up, i_end))
    ends = np.array([i for span in spans for i in span], dtype=np.intp)
    offsets = com_z(body, take(p, ends)) - hip[ends]
    for k, ((_, down), end) in enumerate(zip(flights, landing_ends, strict=True)):
        i_up, i_end = spans[k]
        on = slice(i_up, i_end + 1)
        start_off, end_off = offsets[2 * k], offsets[2 * k + 1]
        s = np.clip((t[on] - down) / max(end - down, 1e-9), 0.0, 1.0)
        blend = s**3 * (10.0 - 15.0 * s + 6.0 * s**2)
        target[on] = hip[on] + start_off + (end_off - start_off) * blend
        window[on] = True
    flying = window & (p.ankle[:, :, 2].min(axis=1) > body.foot_height + 1e-3)
    return steer_com_z(body, p, target, window, feet_follow=flying)
