"""The pelvis's rise and fall in walking: an inverted pendulum, drawn from its force.

Over each stance leg the body vaults like an inverted pendulum: highest at
mid single support, lowest in double support (Perry, *Gait Analysis*, 1992;
Winter, *Biomechanics and Motor Control of Human Movement*). The vertical
ground reaction force is ``m (g + z'')``, so the path is drawn from the force
we want rather than from the legs' reach (whose cusps at heel strike gave
spikes and drops to zero load):

    F / mg = c - d sin(pi s)^k + e cos(pi s)   in single support (s = 0 .. 1)
    F / mg = c - e .. c + e (linear)         in double support

with ``c`` and ``d`` such that the force averages body weight over every
step (the pelvis neither climbs nor sinks) and bottoms at ``valley`` at mid
single support. The force is highest at the edges of single support, which
gives each foot its two peaks (about 1.15-1.2 body weights) and the valley
between them. Twice integrated, high-passed over one step (the force's mean
is zero per step, so this removes only the integration drift) and faded in
from the stand, it becomes the pelvis height, set below the legs' reach so
that the reach limit never cuts it.
"""

from __future__ import annotations

import itertools
from typing import Final

import numpy as np
from scotti.sim.actions.base import lean_ahead
from scotti.sim.actions.com import com_z, steer_com_z
from scotti.sim.actions.curves import box_smooth, ease
from scotti.sim.loads import CONTACT_NONE_M, G
from scotti.sim.skeleton import Array, Body, PoseParams, foot_points, hip_points, leg_reach_z

# Force at mid single support, body weights (Perry; Winter: 0.7-0.8).
VALLEY_BW: Final = 0.74
# The force leans towards the start of single support by this much (body
# weights): weight acceptance after heel strike is the larger peak at
# comfortable speed (Perry), the push-off peak the smaller.
WEIGHT_ACCEPTANCE: Final = 0.04
# The dip's shape over single support, sin(pi s) ** DIP_POWER: below 1 it is
# wide and its edges steep, which lifts the two peaks for a given valley.
DIP_POWER: Final = 0.8
_DIP_MEAN: Final = float(np.mean(np.sin(np.pi * (np.arange(4096) + 0.5) / 4096) ** DIP_POWER))
# Keep the pelvis this far below the legs' reach (the soft minimum's
# softness is 4 mm: 15 mm below it the path is untouched).
REACH_MARGIN_M: Final = 0.015


def pendulum_force(t: Array, swings: list[tuple[float, float]], valley_bw: float) -> Array:
    """F / mg - 1 (N,): single support while a foot swings, ``swings`` in time order.

    Each step's cycle runs from one swing's start to the next's; the last
    swing (the closing step) is left to the fade back to the stand.
    """
    a = np.zeros(len(t))
    for (t_ss, t_ds), (t_next, _) in itertools.pairwise(swings):
        single = t_ds - t_ss
        r = single / (t_next - t_ss)
        # F = c - d sin(pi s)^k + e cos(pi s) over single support, rising from
        # c - e to c + e over double support: mean 1 over the cycle,
        # valley_bw at mid single support.
        d = (1.0 - valley_bw) / (1.0 - r * _DIP_MEAN)
        c = 1.0 + r * d * _DIP_MEAN
        ss = (t >= t_ss) & (t < t_ds)
        ds = (t >= t_ds) & (t < t_next)
        phase = np.pi * (t[ss] - t_ss) / single
        a[ss] = c - 1.0 - d * np.sin(phase) ** DIP_POWER + WEIGHT_ACCEPTANCE * np.cos(phase)
        ramp = (t[ds] - t_ds) / max(t_next - t_ds, 1e-9)
        a[ds] = c - 1.0 + WEIGHT_ACCEPTANCE * (2.0 * ramp - 1.0)
    return a


def swing_intervals(
    body: Body, p: PoseParams, t: Array, ground: Array
) -> list[tuple[float, float]]:
    """(start, end) of every interval in which one foot is wholly off its surface."""
    out: list[tuple[float, float]] = []
    for side in (0, 1):
        feet = foot_points(body, side, p.ankle[:, side], p.foot_yaw[:, side], p.foot_pitch[:, side])
        off = feet[:, :, 2].min(axis=1) - ground[:, side] > CONTACT_NONE_M
        edges = np.flatnonzero(np.diff(np.r_[0, off.astype(np.int8), 0]))
        for a, b in zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True):
            if a > 0 and b < len(t):
                out.append((float(t[a]), float(t[b - 1])))
    return sorted(out)


def pendulum_height(body: Body, p: PoseParams, t: Array, ground: Array, end_s: float) -> Array:
    """Pelvis (N, 3): ``p``'s pelvis with the height of the pendulum gait.

    ``ground`` (N, 2) is the surface under each foot; the single supports
    are read off the feet (``swing_intervals``), so the force follows the
    contacts the loads will see.
    """
    swings = swing_intervals(body, p, t, ground)
    if len(swings) < 2 or len(t) < 2:
        return p.pelvis
    rate = 1.0 / float(t[1] - t[0])
    a = G * pendulum_force(t, swings, VALLEY_BW)
    v = np.cumsum(a) / rate
    z = np.cumsum(v) / rate
    step_s = float(np.median(np.diff([s for s, _ in swings])))
    z = z - box_smooth(z, max(1, round(step_s * rate)))
    # Fade in from the stand until the middle of the first single support,
    # out from the start of the last (the closing step).
    rise_end = 0.5 * (swings[0][0] + swings[0][1])
    fall_start = swings[-1][0]
    fade = ease(t / max(rise_end, 1e-9)) * ease((end_s - t) / max(end_s - fall_start, 1e-9))
    hips = hip_points(body, lean_ahead(body, p).pelvis, p.heading)
    reach = np.minimum(*(leg_reach_z(body, hips[:, s, :2], p.ankle[:, s]) for s in (0, 1)))
    walking = (t >= rise_end) & (t <= fall_start)
    stand = p.pelvis[:, 2]
    base = float((reach - stand - z)[walking].min()) - REACH_MARGIN_M
    pelvis = p.pelvis.copy()
    pelvis[:, 2] = stand + fade * (min(base, 0.0) + z)
    return pelvis


def steer_com_to_pendulum(
    body: Body, p: PoseParams, step_frames: int, envelope: Array
) -> PoseParams:
    """``p`` with the whole-body COM, not only the pelvis, on the pendulum's height.

    The force comes from the COM, and a swinging leg (a sixth of the body's
    mass) lifts and lowers it against the pelvis: left alone it dents single
    support by about 0.1 body weight and the first peak falls below 1.1. The
    COM's offset from the pelvis is smoothed over one step (what the legs
    change slowly, e.g. from stand to walk, stays) and the pelvis is moved
    until the COM follows the pelvis's drawn path plus that offset. The
    correction fades in and out with ``envelope`` (N,) so that the segment
    still starts and ends exactly in the neutral stand.
    """
    com = com_z(body, p)
    offset = box_smooth(com - p.pelvis[:, 2], max(1, step_frames))
    everywhere = np.ones(len(p), dtype=bool)
    steered = steer_com_z(body, p, p.pelvis[:, 2] + offset, everywhere)
    pelvis = p.pelvis.copy()
    pelvis[:, 2] += envelope * (steered.pelvis[:, 2] - p.pelvis[:, 2])
    return p.replace(pelvis=pelvis)
