"""Tiny hand-built motions for the simulator's pressure and writer tests.

Independent of sim-body's kinematics on purpose: the pressure model is tested
against motions whose foot contacts are known exactly.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scotti.models.contract import KP, NO_ACTION
from scotti.sim.writer import FrameLabels, SimInput

RATE_HZ = 16.0
FOOT_LENGTH_M = 0.26
MASS_KG = 70.0


@dataclass(frozen=True)
class SyntheticSubject:
    mass_kg: float = MASS_KG
    height_m: float = 1.75
    foot_length_m: float = FOOT_LENGTH_M
    name: str = "synthetic"


@dataclass(frozen=True)
class SyntheticMotion:
    keypoints: np.ndarray  # (N, 19, 3) world metres, z up
    com: np.ndarray  # (N, 3)
    action: np.ndarray  # (N,) int
    rate_hz: float = RATE_HZ
    subject: SyntheticSubject = field(default_factory=SyntheticSubject)

    @property
    def heading(self) -> np.ndarray:
        return np.zeros(len(self.com))


def _body(com: np.ndarray) -> np.ndarray:
    """Upper-body keypoints hung rigidly under/over the COM (x forward, y left)."""
    n = len(com)
    kp = np.zeros((n, 19, 3))
    offsets = {
        "nose": (0.08, 0.0, 0.62),
        "left_shoulder": (0.0, 0.18, 0.42),
        "right_shoulder": (0.0, -0.18, 0.42),
        "left_elbow": (0.0, 0.22, 0.15),
        "right_elbow": (0.0, -0.22, 0.15),
        "left_wrist": (0.05, 0.22, -0.1),
        "right_wrist": (0.05, -0.22, -0.1),
        "left_hip": (0.0, 0.1, -0.05),
        "right_hip": (0.0, -0.1, -0.05),
    }
    for name, off in offsets.items():
        kp[:, KP[name]] = com + np.array(off)
    return kp


def _place_foot(kp: np.ndarray, side: str, heel: np.ndarray, toe_z: np.ndarray) -> None:
    """Foot along +x from its heel; toes at the foot's length, their height given."""
    toe = heel.copy()
    toe[:, 0] += FOOT_LENGTH_M - 0.02
    toe[:, 2] = toe_z
    sign = 1.0 if side == "left" else -1.0
    kp[:, KP[f"{side}_heel"]] = heel
    kp[:, KP[f"{side}_big_toe"]] = toe + np.array([0.0, -sign * 0.02, 0.0])
    kp[:, KP[f"{side}_small_toe"]] = toe + np.array([-0.03, sign * 0.03, 0.0])
    kp[:, KP[f"{side}_ankle"]] = heel + np.array([0.05, 0.0, 0.08])
    hip = kp[:, KP[f"{side}_hip"]]
    kp[:, KP[f"{side}_knee"]] = 0.5 * (hip + kp[:, KP[f"{side}_ankle"]]) + [0.05, 0, 0]


def standing(n: int = 48) -> SyntheticMotion:
    """Quiet stance, feet 0.2 m apart, COM 1 m up over the midfoot."""
    com = np.tile([0.07, 0.0, 1.0], (n, 1))
    kp = _body(com)
    for side, y in (("left", 0.1), ("right", -0.1)):
        heel = np.tile([-0.05, y, 0.0], (n, 1))
        _place_foot(kp, side, heel, np.zeros(n))
    return SyntheticMotion(kp, com, np.full(n, NO_ACTION))


def jump(n: int = 48, flight_frames: tuple[int, int] = (20, 27)) -> SyntheticMotion:
    """Stand, a ballistic flight for the frames given (feet 0.15 m up), land, stand."""
    t = np.arange(n) / RATE_HZ
    com = np.tile([0.07, 0.0, 1.0], (n, 1))
    a, b = flight_frames
    t0, t1 = a / RATE_HZ, b / RATE_HZ
    tf = t - t0
    in_air = (t >= t0) & (t <= t1)
    v0 = 9.81 * (t1 - t0) / 2.0
    com[in_air, 2] = 1.0 + v0 * tf[in_air] - 0.5 * 9.81 * tf[in_air] ** 2
    kp = _body(com)
    lift = np.where(in_air, 0.15 + (com[:, 2] - 1.0), 0.0)
    for side, y in (("left", 0.1), ("right", -0.1)):
        heel = np.tile([-0.05, y, 0.0], (n, 1))
        heel[:, 2] = lift
        _place_foot(kp, side, heel, lift)
    return SyntheticMotion(kp, com, np.full(n, 3))


def walking(n: int = 64, period_s: float = 1.1, step_m: float = 0.6) -> SyntheticMotion:
    """Forward walking along +x: heel strike, foot flat, heel off, swing."""
    t = np.arange(n) / RATE_HZ
    v = 2.0 * step_m / period_s
    com = np.stack([v * t, np.zeros(n), 1.0 + 0.02 * np.cos(4 * np.pi * t / period_s)], axis=1)
    kp = _body(com)
    for side, y, shift in (("left", 0.1, 0.0), ("right", -0.1, 0.5)):
        phase = (t / period_s + shift) % 1.0
        cycle = np.floor(t / period_s + shift)
        strike_t = (cycle - shift) * period_s
        heel = np.zeros((n, 3))
        heel[:, 1] = y
        heel[:, 0] = v * strike_t + 0.3
        toe_z = np.zeros(n)
        early = phase < 0.08  # heel strike, toes still up
        toe_z[early] = 0.06 * (1 - phase[early] / 0.08)
        off = (phase >= 0.35) & (phase < 0.6)  # heel off, rolling onto the toes
        heel[off, 2] = 0.1 * (phase[off] - 0.35) / 0.25
        swing = phase >= 0.6
        s = (phase[swing] - 0.6) / 0.4
        heel[swing, 0] += 2 * step_m * s
        heel[swing, 2] = 0.1 * (1 - s) + 0.06 * np.sin(np.pi * s)
        toe_z[swing] = 0.08 * (1 - s) + 0.06 * s
        _place_foot(kp, side, heel, toe_z)
    return SyntheticMotion(kp, com, np.full(n, 7))


def synthetic_input(m: SyntheticMotion) -> SimInput:
    """The writer's input for a synthetic motion, labels from its own keypoints."""
    n = len(m.com)
    progress = np.where(m.action >= 0, (np.arange(n) % 16) / 15.0, np.nan)
    labels = FrameLabels(
        keypoints=(m.keypoints - m.com[:, None, :] * [1.0, 1.0, 0.0]).astype(np.float32),
        action=m.action.astype(np.int64),
        progress=progress,
        rep=np.where(m.action >= 0, np.arange(n) // 16, -1),
    )
    subject = m.subject
    return SimInput(m.keypoints, m.com, m.rate_hz, subject.mass_kg, subject.foot_length_m, labels)
