"""Foot loads from a motion: how much each foot carries and where it presses.

The total vertical load is ``m * (g + a_z)`` with ``a_z`` the COM's vertical
acceleration (second finite difference, smoothed); it is shared between the
feet in contact by inverse horizontal distance from the COM to each foot's
centre of pressure (the lever rule for a COM between the feet). A foot whose
keypoints are off the floor carries nothing; with both off (flight) the load
is zero.

On top comes the impact transient of a touch-down (heel strike, landing):
the foot and the soft tissue moving with it, an effective mass of
``IMPACT_MASS_HEEL`` of the body per foot (``IMPACT_MASS_FOREFOOT`` when the
forefoot lands first), stopped from its touch-down speed within
``IMPACT_S``, as a half-sine of that impulse (Whittle 1999,
"Generation and attenuation of transient impulsive forces beneath the foot: a
review", Gait & Posture 10:264-275; Bobbert, Schamhardt and Nigg 1991,
"Calculation of vertical ground reaction force estimates during running from
positional data", J Biomech 24:1095-1105). The rigid kinematics already stop
the foot segments themselves (in ``a_z``); the added mass stands for what
they do not move: heel pad, shank and thigh soft tissue.

Rates: a second difference needs the motion sampled well above the insole's
16 Hz (the scene builder runs at ``scotti.sim.scene.PHYSICS_OVERSAMPLE`` x
16 Hz = 128 Hz) or a 10-30 ms transient and a 0.25 s landing are lost.
:meth:`FootLoads.every` then takes the insole's samples: one insole frame is
the load at the frame time (the row scan of a frame takes a few ms, shorter
than the internal step, so it is not averaged over the 62.5 ms frame period).

Along the foot the COP follows the foot's pitch: heel only on the floor ->
heel, toes only -> forefoot, rolling onto the hallux as the heel rises; flat
-> under the COM's projection (further back towards the heel when both feet
are flat). Across the foot it rolls to the edge the COM
leans over (side walking).

:mod:`scotti.sim.pressure` renders these loads into taxel maps.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
from scotti.models.contract import KP

G: Final = 9.81  # m/s^2

# Feet in the order the frames carry them: 0 left, 1 right (firmware Foot).
_HEEL: Final = (KP["left_heel"], KP["right_heel"])
_BIG_TOE: Final = (KP["left_big_toe"], KP["right_big_toe"])
_SMALL_TOE: Final = (KP["left_small_toe"], KP["right_small_toe"])

# A foot keypoint carries load only while it touches the floor: fully at or
# below CONTACT_FULL_M, not at all above CONTACT_NONE_M, linearly in between.
# The kinematics put a standing foot's keypoints exactly on the surface
# (z - ground = 0), so the ramp is not a tolerance for hovering feet: it
# stands for the sole's compression as the load builds, the first few
# millimetres of heel pad and shoe sole squeezed at touch-down and released
# at lift-off (the heel pad alone deforms by several millimetres under body
# weight: Aerts et al. 1995, "The mechanical properties of the human heel
# pad", J Biomech 28:1299-1308). It spreads a touch-down over a few
# milliseconds of the internal rate, no more. A wider ramp (load from
# 20 mm up) would let a foot still in the air take part of the weight, so
# every step lands early and lifts off late: 36-45 % double support against
# 22-32 % in real gaitpdb walking (docs/real-data.md). What a foot in the
# air does not carry goes to the foot on the floor (the sharing below
# normalises over the feet in contact).
CONTACT_FULL_M: Final = 0.001
CONTACT_NONE_M: Final = 0.004
# Where along a loaded foot the load goes is a separate, wider weighting of
# its two ends: an end within SOLE_FULL_M of the floor bears its part fully,
# one above SOLE_NONE_M none (linear in between). The keypoints describe a
# rigid sole; the real one compresses and bends, so a heel a few millimetres
# up (a flat landing pitched a degree toes-down) still bears once the foot is
# loaded. These are the bounds the COP calibration below was made with.
SOLE_FULL_M: Final = 0.005
SOLE_NONE_M: Final = 0.020
# COP along the foot (0 heel, 1 hallux tip) for heel-only and flat contact.
# The flat foot's COP follows the COM's projection within (0.30, 0.72): in
# walking it thus leaves the heel once the heel rocker is done and reaches
# the metatarsal heads (0.66-0.74 of the foot, sim/plantar.py) by heel-off.
# These bounds and the forefoot roll below were calibrated together so that
# walking's regional load shares (heel / midfoot / metatarsal heads / toes)
# meet the in-shoe norms in sim/REALISM.md (``scotti sim realism``).
_COP_HEEL: Final = 0.10
_COP_FLAT_RANGE: Final = (0.30, 0.72)
# A foot coming down flat (heel and forefoot touching together, a midfoot
# strike or a side step) first bears load on the middle of its sole, not
# under a COM that is still behind it: at touch-down the flat COP is kept at
# least this far along (a strike index of about one half, Cavanagh &
# Lafortune 1980), easing back to the COM's projection over _LANDING_S, the
# start of weight acceptance (our choice: about the time a foot coming down
# at 0.3-0.4 m/s takes over the sole's 15 mm weighting band above).
_COP_FLAT_LANDING: Final = 0.55
_LANDING_S: Final = 0.05
# Both feet flat (standing, squatting, a jump's crouch): nothing is rolling
# over a heel or forefoot rocker, so the COP follows the COM back towards the
# heel pad, down to this far along. With the walking floor (0.30) a squat's
# COM, which starts 0.33-0.41 along the foot and moves ~0.09 back as the hips
# go back, pinned the COP at 0.30 for 57-100 % of each squat in 6 of 8
# drawn people: depth then left no trace in the pressure maps and squat
# progress could not be read from them. Walking never has both feet flat at once (the trailing heel
# is up before the leading forefoot lands), so its calibration is untouched.
_COP_BOTH_FLAT_FLOOR: Final = 0.15
# Toes-only contact: on the metatarsal heads through push-off, rolling toward
# the hallux only as the foot pitches steeply (sine of the pitch from the
# first to the second value), i.e. as the load runs out. The COP does not
# follow a COM ahead of the foot: the body falls forward over the forefoot
# rocker. (Walking's COP at toe-off thus ends near 0.75, at the base of the
# toes, rather than under the hallux: a compromise with the toes' 10-15 %
# load share in this contact model.)
_COP_FOREFOOT: Final = 0.69
_COP_HALLUX: Final = 0.86
_PITCH_SIN_ROLL: Final = (0.45, 0.90)
# Across the foot: the COM this far medial of the foot is neutral (normal
# stance width); the roll saturates over the given scale.
_NEUTRAL_MEDIAL_M: Final = 0.09
_ROLL_SCALE_M: Final = 0.12
# Inverse-distance sharing: distances below this do not dominate.
_SHARE_EPS_M: Final = 0.03
# Impact transient: effective mass per foot as a share of body mass, heel
# first and forefoot first (Lieberman et al. 2010, "Foot strike patterns and
# collision forces in habitually barefoot versus shod runners", Nature
# 463:531-535: 6.8 % and 1.7 %; a forefoot landing is caught by the ankle),
# and how long the heel pad and shoe take to stop it (Whittle 1999: 10-30 ms).
IMPACT_MASS_HEEL: Final = 0.068
IMPACT_MASS_FOREFOOT: Final = 0.017
IMPACT_S: Final = 0.02


@dataclass(frozen=True)
class FootLoads:
    """Per frame and foot (axis 1: 0 left, 1 right)."""

    load_n: np.ndarray  # (N, 2) vertical force on the foot
    cop_u: np.ndarray  # (N, 2) along the foot, 0 heel .. 1 toes
    cop_medial: np.ndarray  # (N, 2) -1 lateral edge .. +1 medial edge
    contact: np.ndarray  # (N, 2) 0 in the air .. 1 on the floor
    total_n: np.ndarray  # (N,) m (g + a_z), before the contact gate
    impact_n: np.ndarray | None = None  # (N, 2) touch-down transient, included in load_n

    def every(self, step: int) -> FootLoads:
        """Every ``step``-th sample: the insole's frames from loads at the internal rate."""
        impact = None if self.impact_n is None else self.impact_n[::step]
        return FootLoads(
            self.load_n[::step],
            self.cop_u[::step],
            self.cop_medial[::step],
            self.contact[::step],
            self.total_n[::step],
            impact,
        )


def _ramp_down(
    z: np.ndarray, full: float = CONTACT_FULL_M, none: float = CONTACT_NONE_M
) -> np.ndarray:
    """1 at/below ``full``, 0 at/above ``none``, linear in between."""
    return np.clip((none - z) / (none - full), 0.0, 1.0)


def flat_landing(contact: np.ndarray, flat: np.ndarray, rate_hz: float) -> np.ndarray:
    """(N, 2): 1 at the touch-down of a foot that lands flat, easing to 0 over _LANDING_S.

    ``contact`` (N, 2) > 0 while a foot touches; ``flat`` (N, 2) how flat it
    is (1: both ends bear) -- taken at the touch-down sample. A foot already
    down at the first sample did not land.
    """
    touched = contact > 0
    before = np.concatenate([touched[:1], touched[:-1]])
    index = np.arange(len(contact))[:, None]
    last = np.maximum.accumulate(np.where(touched & ~before, index, -1), axis=0)
    since_s = (index - last) / rate_hz
    at_touch = np.take_along_axis(flat, np.maximum(last, 0), axis=0)
    easing = np.clip(1.0 - since_s / _LANDING_S, 0.0, 1.0)
    return np.where(touched & (last >= 0), at_touch * easing, 0.0)


def vertical_acceleration(com_z: np.ndarray, rate_hz: float) -> np.ndarray:
    """COM vertical acceleration (m/s^2): central second difference, smoothed [1 2 1]/4."""
    z = np.asarray(com_z, dtype=np.float64)
    if z.size < 3:
        return np.zeros_like(z)
    padded = np.concatenate([z[:1], z, z[-1:]])
    acc = (padded[2:] - 2.0 * padded[1:-1] + padded[:-2]) * rate_hz * rate_hz
    acc_padded = np.concatenate([acc[:1], acc, acc[-1:]])
    return 0.25 * acc_padded[:-2] + 0.5 * acc_padded[1:-1] + 0.25 * acc_padded[2:]


def foot_loads(
    keypoints: np.ndarray,
    com: np.ndarray,
    rate_hz: float,
    mass_kg: float,
    ground_z: np.ndarray | None = None,
) -> FootLoads:
    """Loads and centres of pressure of both feet.

    ``keypoints`` (N, 19, 3) world, ``com`` (N, 3); ``ground_z`` (N, 2): the
    surface height under each foot (a step), None for a flat floor.
    """
    kp = np.asarray(keypoints, dtype=np.float64)
    com = np.asarray(com, dtype=np.float64)
    ground = np.zeros((len(kp), 2)) if ground_z is None else np.asarray(ground_z, np.float64)
    heel = kp[:, _HEEL, :]  # (N, 2, 3)
    toe = 0.5 * (kp[:, _BIG_TOE, :] + kp[:, _SMALL_TOE, :])  # (N, 2, 3)
    toe_z = np.minimum(kp[:, _BIG_TOE, 2], kp[:, _SMALL_TOE, 2]) - ground
    heel_z = heel[..., 2] - ground
    contact = _ramp_down(np.minimum(heel_z, toe_z))  # whether the foot carries load
    # Which end bears it (the sole's wider weighting, see SOLE_FULL_M).
    c_heel = _ramp_down(heel_z, SOLE_FULL_M, SOLE_NONE_M)
    c_toe = _ramp_down(toe_z, SOLE_FULL_M, SOLE_NONE_M)

    # Foot axis on the floor, heel -> toes, and the medial direction:
    # to the right of the left foot, to the left of the right foot.
    axis = toe[..., :2] - heel[..., :2]
    length = np.maximum(np.linalg.norm(axis, axis=-1), 1e-3)
    fwd = axis / length[..., None]
    left_of_foot = np.stack([-fwd[..., 1], fwd[..., 0]], axis=-1)
    medial_dir = left_of_foot * np.array([-1.0, 1.0])[None, :, None]

    rel = com[:, None, :2] - heel[..., :2]  # (N, 2, 2)
    u_com = np.einsum("nfk,nfk->nf", rel, fwd) / length
    settling = flat_landing(contact, c_heel * c_toe, rate_hz)  # 1 at a flat touch-down
    both_flat = np.minimum(c_heel, c_toe).min(axis=1, keepdims=True)  # (N, 1), 1: both down flat
    floor_still = _COP_FLAT_RANGE[0] - (_COP_FLAT_RANGE[0] - _COP_BOTH_FLAT_FLOOR) * both_flat
    floor_u = floor_still + (_COP_FLAT_LANDING - floor_still) * settling
    u_flat = np.clip(u_com, floor_u, _COP_FLAT_RANGE[1])
    pitch_sin = (heel_z - toe_z) / np.maximum(np.linalg.norm(toe - heel, axis=-1), 1e-3)
    lo, hi = _PITCH_SIN_ROLL
    heel_rise = np.clip((pitch_sin - lo) / (hi - lo), 0.0, 1.0)
    # On the toes the COP is under the forefoot, as near the COM as it can be.
    u_pitch = _COP_FOREFOOT + (_COP_HALLUX - _COP_FOREFOOT) * heel_rise
    u_toe = u_pitch
    w_flat = c_heel * c_toe
    w_heel = c_heel * (1.0 - c_toe)
    w_toe = c_toe * (1.0 - c_heel)
    w_sum = w_flat + w_heel + w_toe
    cop_u = np.where(
        w_sum > 0,
        (w_flat * u_flat + w_heel * _COP_HEEL + w_toe * u_toe) / np.maximum(w_sum, 1e-12),
        0.5 * sum(_COP_FLAT_RANGE),
    )

    # COP point on the floor, then the COM's medial offset from it.
    cop_xy = heel[..., :2] + axis * cop_u[..., None]
    medial_off = np.einsum("nfk,nfk->nf", com[:, None, :2] - cop_xy, medial_dir)
    cop_medial = np.tanh((medial_off - _NEUTRAL_MEDIAL_M) / _ROLL_SCALE_M)

    # Share by inverse horizontal distance (the lever rule between two feet).
    dist = np.linalg.norm(com[:, None, :2] - cop_xy, axis=-1)
    share = contact / (dist + _SHARE_EPS_M)
    share_sum = share.sum(axis=1, keepdims=True)
    share = np.where(share_sum > 0, share / np.maximum(share_sum, 1e-12), 0.0)

    total = mass_kg * (G + vertical_acceleration(com[:, 2], rate_hz))
    gate = np.minimum(1.0, contact.sum(axis=1))
    load = np.maximum(total * gate, 0.0)[:, None] * share
    impact = impact_forces(heel_z, toe_z, rate_hz, mass_kg)
    return FootLoads(load + impact, cop_u, cop_medial, contact, total, impact)


def impact_forces(
    heel_z: np.ndarray, toe_z: np.ndarray, rate_hz: float, mass_kg: float
) -> np.ndarray:
    """(N, 2) newtons: a half-sine per touch-down of each foot.

    ``heel_z``, ``toe_z`` (N, 2): heights above each foot's surface. A
    touch-down is where the lower of them sinks to CONTACT_FULL_M; the speed
    is its descent over the sample before. The pulse carries the effective
    mass's momentum, ``m_eff * v``, over IMPACT_S, evaluated at the sample
    times (so a rate well above 1 / IMPACT_S resolves it).
    """
    z = np.minimum(np.asarray(heel_z, np.float64), np.asarray(toe_z, np.float64))
    heel_first = np.asarray(heel_z) <= np.asarray(toe_z)
    out = np.zeros_like(z)
    if len(z) < 2:
        return out
    dt = 1.0 / rate_hz
    t = np.arange(len(z)) * dt
    span = int(np.ceil(IMPACT_S * rate_hz)) + 1
    for foot in range(z.shape[1]):
        h = z[:, foot]
        down = np.flatnonzero((h[:-1] > CONTACT_FULL_M) & (h[1:] <= CONTACT_FULL_M)) + 1
        for i in down.tolist():
            v = (h[i - 1] - h[i]) / dt
            share = IMPACT_MASS_HEEL if heel_first[i, foot] else IMPACT_MASS_FOREFOOT
            m_eff = share * mass_kg
            # Where between the two samples the foot reached CONTACT_FULL_M.
            t0 = t[i - 1] + dt * (h[i - 1] - CONTACT_FULL_M) / max(h[i - 1] - h[i], 1e-12)
            window = slice(i, min(len(z), i + span))
            s = (t[window] - t0) / IMPACT_S
            pulse = np.where((s >= 0) & (s <= 1), np.sin(np.pi * np.clip(s, 0.0, 1.0)), 0.0)
            out[window, foot] += 0.5 * np.pi * m_eff * v / IMPACT_S * pulse
    return out
