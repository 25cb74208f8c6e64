"""What every recipe shares: where the person stands, the request, the result.

A recipe starts and ends in the neutral stand (feet flat at the person's
stance width and toe-out, arms hanging) at a ``Place`` and returns a ``Segment`` of per-frame pose
parameters. Because every segment begins and ends in that pose with zero
velocity, segments join without a jump or a kink.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scotti.models.contract import STANDING
from scotti.sim.actions.curves import bump, soft_min
from scotti.sim.motion import Subject
from scotti.sim.skeleton import (
    LEFT,
    TOE_OUT,  # re-exported: the default toe-out; a person's own is ``Body.toe_out``
    Body,
    PoseParams,
    axes,
    foot_points,
    hip_points,
    leg_reach_z,
)

Array = npt.NDArray[np.float64]

__all__ = [
    "TOE_OUT",
    "ActionSpec",
    "Context",
    "Place",
    "Segment",
    "finalize",
    "foot_yaw",
    "neutral",
    "stance_lateral",
    "stand",
]
# Elbows hang slightly bent.
ELBOW_REST = 0.15
# Softness (metres) of the reach limit on the pelvis height.
REACH_SOFTNESS = 0.004
# The body leans forwards a little over the ankles: the hips this far ahead
# of where the recipes put them (x height / 1.75) puts the standing COM
# 4-6 cm in front of the ankle joints, where quiet standing has it (Winter
# 1995, "Human balance and posture control during standing and walking",
# Gait & Posture 3:193-214); the calf muscles hold that lean.
HIPS_AHEAD_M = 0.045


@dataclass(frozen=True)
class Place:
    """Where a neutral stand is: mid-hip x, y on the floor and the heading."""

    x: float
    y: float
    heading: float
    floor_z: float = 0.0

    def point(self, forward: float, left: float) -> Array:
        """A floor point given in the person's frame, in world x, y."""
        f, lft = axes(self.heading)
        return np.array([self.x, self.y]) + forward * f[:2] + left * lft[:2]

    def xy(self, forward: float, left: float) -> tuple[float, float]:
        """``point`` as a plain pair (for a ``Plant``)."""
        x, y = self.point(forward, left)
        return float(x), float(y)


@dataclass(frozen=True)
class ActionSpec:
    """One script entry, validated by the scene (see ``scene.py``)."""

    action: str
    reps: int | None = None
    duration_s: float | None = None
    tempo: float = 1.0
    depth: float | None = None  # None: the subject's own depth
    step_length_m: float | None = None  # None: from height
    step_height_m: float = 0.2
    direction: str = "left"  # side walking only
    turn_rad: float = 0.0  # walking: heading change spread over the walk (an arc)
    vary: bool = False  # speed changes, and for walking turns, drawn from the seed


@dataclass(frozen=True)
class Context:
    """Everything a recipe draws on besides the request itself."""

    body: Body
    subject: Subject
    rate_hz: float
    rng: np.random.Generator

    def times(self, duration_s: float) -> Array:
        """Sample times of a segment lasting ``duration_s``."""
        return np.arange(max(1, round(duration_s * self.rate_hz))) / self.rate_hz

    def jitter(self, spread: float, size: int | None = None) -> Array:
        """Multiplicative per-repetition variation around 1."""
        return np.asarray(1.0 + spread * self.rng.standard_normal(size), dtype=np.float64)

    def rep_durations(self, nominal_s: float, tempo: float, reps: int) -> Array:
        """Duration of each repetition: nominal / tempo, varied by the subject's spread."""
        spread = self.subject.tempo_variation
        return np.clip(self.jitter(spread, reps), 0.7, 1.3) * nominal_s / tempo


@dataclass(frozen=True)
class Segment:
    """A recipe's result: pose drive, labels and where it ended."""

    params: PoseParams
    action: npt.NDArray[np.int64]  # (N,)
    end: Place
    ground_z: Array  # (N, 2) surface height under each foot

    def __len__(self) -> int:
        return len(self.params)


def stance_lateral(body: Body, side: int) -> float:
    """Where a foot stands in the neutral stand: metres to the person's left (< 0: right)."""
    return (0.5 if side == LEFT else -0.5) * body.stance_width


def foot_yaw(body: Body, side: int, heading: float) -> float:
    """A standing foot's yaw: the heading turned out by the person's toe-out."""
    return heading + (body.toe_out[0] if side == LEFT else -body.toe_out[1])


def neutral(body: Body, place: Place, n: int) -> PoseParams:
    """The neutral stand held for ``n`` frames: the person's stance width and toe-out."""
    heading = np.full(n, place.heading)
    ankles = np.stack(
        [
            np.r_[place.point(0.0, stance_lateral(body, side)), place.floor_z + body.foot_height]
            for side in (0, 1)
        ]
    )
    pelvis = np.r_[place.x, place.y, place.floor_z + body.stand_hip_z]
    return PoseParams(
        pelvis=np.tile(pelvis, (n, 1)),
        heading=heading,
        lean=np.zeros(n),
        ankle=np.tile(ankles, (n, 1, 1)),
        foot_yaw=np.stack([heading + body.toe_out[0], heading - body.toe_out[1]], axis=1),
        foot_pitch=np.zeros((n, 2)),
        shoulder_flex=np.zeros((n, 2)),
        elbow_flex=np.full((n, 2), ELBOW_REST),
    )


def lean_ahead(body: Body, p: PoseParams) -> PoseParams:
    """``p`` with the hips moved HIPS_AHEAD_M (scaled by height) along the heading."""
    forward, _ = axes(p.heading)
    ahead = HIPS_AHEAD_M * body.height / 1.75
    return p.replace(pelvis=p.pelvis + ahead * forward * np.array([1.0, 1.0, 0.0]))


def finalize(body: Body, p: PoseParams) -> PoseParams:
    """Lean over the ankles, keep the feet on or above the floor and the pelvis within reach."""
    p = lean_ahead(body, p)
    ankle = p.ankle.copy()
    for side in (0, 1):
        feet = foot_points(body, side, ankle[:, side], p.foot_yaw[:, side], p.foot_pitch[:, side])
        below = np.minimum(feet[:, :, 2].min(axis=1), 0.0)
        ankle[:, side, 2] -= below
    hips = hip_points(body, p.pelvis, p.heading)
    limits = [leg_reach_z(body, hips[:, s, :2], ankle[:, s]) for s in (0, 1)]
    pelvis = p.pelvis.copy()
    pelvis[:, 2] = soft_min([pelvis[:, 2], *limits], REACH_SOFTNESS)
    return p.replace(ankle=ankle, pelvis=pelvis)


def stand(ctx: Context, place: Place, duration_s: float) -> Segment:
    """A quiet stand (labelled ``standing``): a small sway of the body over the feet."""
    t = ctx.times(duration_s)
    n = len(t)
    p = neutral(ctx.body, place, n)
    envelope = bump(t / max(duration_s, 1e-9))
    phase = ctx.rng.uniform(0, 2 * np.pi)
    f, lft = axes(place.heading)
    sway = envelope[:, None] * (
        0.012 * np.sin(2 * np.pi * 0.4 * t + phase)[:, None] * lft
        + 0.006 * np.sin(2 * np.pi * 0.25 * t)[:, None] * f
    )
    p = p.replace(pelvis=p.pelvis + sway, shoulder_flex=p.shoulder_flex + 0.03 * envelope[:, None])
    return Segment(
        finalize(ctx.body, p), np.full(n, STANDING, dtype=np.int64), place, np.zeros((n, 2))
    )
