"""Where a walk goes: speed changes, a walkway with turns, feet that keep clear.

A lab walkway is straight for 6-12 m, then the person turns round (or
turns a corner) over a few shorter, slower steps and walks on; in between
the heading wanders a little. Speed drifts slowly over the steps. In sharp
turns the path cuts corners, so a swinging foot is kept to its own side of
the standing one.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scotti.sim.actions.base import ActionSpec, Context
from scotti.sim.actions.curves import bump
from scotti.sim.actions.footsteps import FootTrack
from scotti.sim.skeleton import LEFT, RIGHT, Array

# A lab walkway: straight for WALKWAY_M (uniform), then a turn round (or a
# corner) over TURN_STEPS shorter, slower steps; a gentle wander in between.
WALKWAY_M = (6.0, 12.0)
TURN_STEPS = 4
TURN_STEP_LENGTH = 0.65
SHARP_TURN_RAD = 0.35  # a step turning more than this stands wider
# A swinging ankle passes the standing one at least this far away (softly).
CLEARANCE_M = 0.07
CLEARANCE_SOFT_M = 0.005
WANDER_RAD = 0.03  # SD of the heading drift per step (smoothed)
# Speed changes: two slow sinusoids over the steps (periods in steps).
SPEED_PERIODS = ((20.0, 40.0), (7.0, 15.0))


def speed_factors(ctx: Context, steps: int, amplitude: float) -> Array:
    """Per-step speed relative to the person's own: slow drifts of +-``amplitude``."""
    k = np.arange(steps)
    out = np.ones(steps)
    for weight, (low, high) in zip((0.7, 0.5), SPEED_PERIODS, strict=True):
        period, phase = ctx.rng.uniform(low, high), ctx.rng.uniform(0, 2 * np.pi)
        out += weight * amplitude * np.sin(2 * np.pi * k / period + phase)
    return out


def headings(ctx: Context, spec: ActionSpec, lengths: Array, turns: bool) -> tuple[Array, Array]:
    """Heading change per step (radians) and a step-length factor (shorter in turns).

    The last two steps never turn: the walk ends straight, in the neutral stand.
    """
    steps = len(lengths)
    turn = np.zeros(steps)
    scale = np.ones(steps)
    free = max(1, steps - 2)  # steps that may turn
    if not turns:
        return turn, scale
    turn[:free] += spec.turn_rad / free
    if not spec.vary:
        return turn, scale
    wander = ctx.rng.standard_normal(steps) * WANDER_RAD
    turn[:free] += np.convolve(wander, np.ones(3) / 3, mode="same")[:free]
    walkway = ctx.rng.uniform(*WALKWAY_M)
    travelled, k = 0.0, 0
    while k < free:
        travelled += lengths[k]
        if travelled >= walkway and k + 1 + TURN_STEPS <= free:
            angle = np.pi * ctx.rng.uniform(0.85, 1.1) if ctx.rng.random() < 0.7 else np.pi / 2
            sign = 1.0 if ctx.rng.random() < 0.5 else -1.0
            turn[k + 1 : k + 1 + TURN_STEPS] += sign * angle / TURN_STEPS
            scale[k + 1 : k + 1 + TURN_STEPS] = TURN_STEP_LENGTH
            k += TURN_STEPS
            travelled, walkway = 0.0, ctx.rng.uniform(*WALKWAY_M)
        k += 1
    return turn, scale


def keep_clear(left: FootTrack, right: FootTrack, left_axis: Array) -> tuple[FootTrack, FootTrack]:
    """Keep a swinging foot on its own side of the standing one (turns cut corners).

    Across the body (``left_axis`` (N, 2), the person's left) a swinging
    ankle stays about CLEARANCE_M to its side of the standing ankle. The push
    fades in after lift-off and out before touch-down, so the swing still
    leaves and lands where its plants are.
    """
    feet = [left, right]
    for swing in (LEFT, RIGHT):
        airborne = ~feet[swing].stance
        if not airborne.any():
            continue
        # Swing progress 0..1 within each run of swinging frames.
        edges = np.flatnonzero(np.diff(np.r_[0, airborne.astype(np.int8), 0]))
        fade = np.zeros(len(airborne))
        for a, b in zip(edges[::2], edges[1::2], strict=True):
            fade[a:b] = bump((np.arange(a, b) - a + 1) / (b - a + 1))
        sign = 1.0 if swing == LEFT else -1.0
        apart = sign * np.sum(
            (feet[swing].ankle[:, :2] - feet[1 - swing].ankle[:, :2]) * left_axis, axis=1
        )
        # Soft maximum of the separation and the clearance: unchanged when well apart.
        gap = (apart - CLEARANCE_M) / CLEARANCE_SOFT_M
        wanted = CLEARANCE_M + CLEARANCE_SOFT_M * np.logaddexp(0.0, gap)
        ankle = feet[swing].ankle.copy()
        ankle[:, :2] += (sign * fade * (wanted - apart))[:, None] * left_axis
        feet[swing] = replace(feet[swing], ankle=ankle)
    return feet[LEFT], feet[RIGHT]


def knot_velocity(y: Array, knot_t: Array) -> Array:
    """Velocities at the keyframes: finite differences, zero at the start and at the end stand."""
    v = np.gradient(y, knot_t, axis=0)
    v[[0, -2, -1]] = 0.0
    return np.asarray(v, dtype=np.float64)
