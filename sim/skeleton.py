"""The 19-keypoint body: segment lengths from height, forward and inverse kinematics.

Segment lengths are fractions of body height H after Drillis and Contini
(1966), as drawn in Winter, *Biomechanics and Motor Control of Human
Movement*, 4th ed., Fig. 4.1; segment masses and centres of mass after
Dempster, from Winter's Table 4.1.

==========================  ========  ===============================================
quantity                    x H       used for
==========================  ========  ===============================================
thigh (hip -> knee)         0.245     hip -> knee keypoints
shank (knee -> ankle)       0.246     knee -> ankle keypoints
foot length (heel -> toe)   0.152     heel -> big toe, along the foot
foot height (ankle)         0.039     ankle above the sole
foot width                  0.055     big toe / small toe spread
hip width                   0.191     hip keypoints 0.5 of it apart (joint centres) *
shoulder width              0.259     shoulder keypoints 0.8 of it apart (joints) *
upper arm                   0.186     shoulder -> elbow
forearm                     0.146     elbow -> wrist
hand                        0.108     hand centre of mass only
hip joint height            0.530     standing mid-hip height
shoulder height             0.818     trunk = 0.818 - 0.530 = 0.288 H
nose height                 0.905     between chin (0.870) and eye (0.936)
==========================  ========  ===============================================

* Drillis and Contini give outer breadths; COCO keypoints sit on the joints,
so the keypoint spacing is the stated share of the breadth (our choice).

Masses (share of body mass) and centre of mass (share of the segment from its
proximal end), Dempster via Winter: hand 0.006 / 0.506, forearm 0.016 / 0.430,
upper arm 0.028 / 0.436, foot 0.0145 / 0.50 (ankle to the metatarsal heads),
shank 0.0465 / 0.433, thigh 0.100 / 0.433, trunk-head-neck 0.578 / 0.66
(hip to shoulder, from the hip). They sum to 1.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt
from scotti.models.contract import KP, NUM_KEYPOINTS

Array = npt.NDArray[np.float64]

# Fractions of height H (Drillis and Contini via Winter, Fig. 4.1).
THIGH: Final = 0.245
SHANK: Final = 0.246
FOOT_LENGTH: Final = 0.152
FOOT_HEIGHT: Final = 0.039
FOOT_WIDTH: Final = 0.055
HIP_WIDTH: Final = 0.191
SHOULDER_WIDTH: Final = 0.259
UPPER_ARM: Final = 0.186
FOREARM: Final = 0.146
HAND: Final = 0.108
HIP_HEIGHT: Final = 0.530
SHOULDER_HEIGHT: Final = 0.818
NOSE_HEIGHT: Final = 0.905
# Keypoint spacing as a share of the outer breadth (joint centres, our choice).
HIP_JOINT_SHARE: Final = 0.5
SHOULDER_JOINT_SHARE: Final = 0.8
# The nose sits this far (x H) in front of the neck.
NOSE_FORWARD: Final = 0.055
# The ankle sits this far in front of the heel, as a share of foot length.
ANKLE_FROM_HEEL: Final = 0.22
# The small toe's tip, as a share of foot length from the heel.
SMALL_TOE_AT: Final = 0.80
# Arms hang this far out from the trunk (radians), so hands clear the hips.
ARM_ABDUCTION: Final = 0.12
# Standing toe-out of each foot (radians) unless the person's own is given.
TOE_OUT: Final = 0.08

# Dempster (Winter Table 4.1): (mass share, centre of mass from the proximal end).
MASS_HAND: Final = (0.006, 0.506)
MASS_FOREARM: Final = (0.016, 0.430)
MASS_UPPER_ARM: Final = (0.028, 0.436)
MASS_FOOT: Final = (0.0145, 0.50)
MASS_SHANK: Final = (0.0465, 0.433)
MASS_THIGH: Final = (0.100, 0.433)
MASS_TRUNK_HEAD_NECK: Final = (0.578, 0.66)

LEFT: Final = 0
RIGHT: Final = 1
SIDES: Final = ("left", "right")


@dataclass(frozen=True)
class Body:
    """Segment lengths in metres for one person (see the table above)."""

    height: float
    thigh: float
    shank: float
    foot_length: float
    foot_height: float
    foot_width: float
    hip_spacing: float  # between the two hip keypoints
    shoulder_spacing: float  # between the two shoulder keypoints
    upper_arm: float
    forearm: float
    hand: float
    trunk: float  # mid-hip -> neck (mid-shoulder)
    nose_up: float  # neck -> nose, along the trunk
    nose_forward: float  # neck -> nose, forwards
    # Standing: ankle centres this far apart, feet turned out (left, right) radians.
    stance_width: float = 0.0
    toe_out: tuple[float, float] = (TOE_OUT, TOE_OUT)

    @classmethod
    def from_height(
        cls,
        height: float,
        foot_length: float | None = None,
        *,
        stance_width: float | None = None,
        toe_out: tuple[float, float] = (TOE_OUT, TOE_OUT),
    ) -> Body:
        """Lengths from height; standing width defaults to the hip keypoints' spacing."""
        h = float(height)
        hip_spacing = HIP_JOINT_SHARE * HIP_WIDTH * h
        return cls(
            height=h,
            thigh=THIGH * h,
            shank=SHANK * h,
            foot_length=FOOT_LENGTH * h if foot_length is None else float(foot_length),
            foot_height=FOOT_HEIGHT * h,
            foot_width=FOOT_WIDTH * h,
            hip_spacing=hip_spacing,
            shoulder_spacing=SHOULDER_JOINT_SHARE * SHOULDER_WIDTH * h,
            upper_arm=UPPER_ARM * h,
            forearm=FOREARM * h,
            hand=HAND * h,
            trunk=(SHOULDER_HEIGHT - HIP_HEIGHT) * h,
            nose_up=(NOSE_HEIGHT - SHOULDER_HEIGHT) * h,
            nose_forward=NOSE_FORWARD * h,
            stance_width=hip_spacing if stance_width is None else float(stance_width),
            toe_out=(float(toe_out[0]), float(toe_out[1])),
        )

    @property
    def leg(self) -> float:
        return self.thigh + self.shank

    @property
    def stand_hip_z(self) -> float:
        """Mid-hip height standing with straight legs, feet flat."""
        return self.foot_height + self.leg

    def foot_local(self, side: int) -> Array:
        """Heel, big toe, small toe (3, 3) relative to the ankle, foot frame, flat.

        Foot frame: x along the foot, y to the person's left, z up.
        """
        back = ANKLE_FROM_HEEL * self.foot_length
        inward = -1.0 if side == LEFT else 1.0  # medial is to the right of a left foot
        return np.array(
            [
                [-back, 0.0, -self.foot_height],
                [self.foot_length - back, inward * 0.25 * self.foot_width, -self.foot_height],
                [
                    SMALL_TOE_AT * self.foot_length - back,
                    -inward * 0.45 * self.foot_width,
                    -self.foot_height,
                ],
            ]
        )


@dataclass(frozen=True)
class PoseParams:
    """Per-frame drive of the skeleton (N frames); angles in radians.

    ``ankle``, ``foot_yaw`` and ``foot_pitch`` are indexed [frame, side]
    with side 0 left, 1 right; foot yaw is absolute (world), pitch > 0 lifts
    the toes. Trunk lean > 0 bends forwards; shoulder flexion > 0 swings the
    arm forwards; elbow flexion > 0 bends it.
    """

    pelvis: Array  # (N, 3) mid-hip, world
    heading: Array  # (N,)
    lean: Array  # (N,)
    ankle: Array  # (N, 2, 3)
    foot_yaw: Array  # (N, 2)
    foot_pitch: Array  # (N, 2)
    shoulder_flex: Array  # (N, 2)
    elbow_flex: Array  # (N, 2)

    def __len__(self) -> int:
        return len(self.heading)

    @staticmethod
    def concatenate(parts: list[PoseParams]) -> PoseParams:
        names = PoseParams.__dataclass_fields__
        return PoseParams(**{n: np.concatenate([getattr(p, n) for p in parts]) for n in names})

    def replace(self, **arrays: Array) -> PoseParams:
        values = {n: getattr(self, n) for n in PoseParams.__dataclass_fields__}
        values.update(arrays)
        return PoseParams(**values)


# --- rotations --------------------------------------------------------------


def axes(yaw: npt.ArrayLike) -> tuple[Array, Array]:
    """Forward and left unit vectors (..., 3) of a yaw angle (..., )."""
    y = np.asarray(yaw, dtype=np.float64)
    zero = np.zeros_like(y)
    forward = np.stack([np.cos(y), np.sin(y), zero], axis=-1)
    left = np.stack([-np.sin(y), np.cos(y), zero], axis=-1)
    return forward, left


def foot_to_world(local: Array, yaw: Array, pitch: Array) -> Array:
    """Rotate foot-frame offsets (P, 3) by pitch then yaw (N,) -> (N, P, 3)."""
    c, s = np.cos(pitch)[:, None], np.sin(pitch)[:, None]
    x = local[None, :, 0] * c - local[None, :, 2] * s  # (N, P)
    z = local[None, :, 0] * s + local[None, :, 2] * c
    forward, left = axes(yaw)  # (N, 3)
    return np.asarray(
        x[..., None] * forward[:, None, :]
        + local[None, :, 1, None] * left[:, None, :]
        + z[..., None] * np.array([0.0, 0.0, 1.0])
    )


def foot_points(body: Body, side: int, ankle: Array, yaw: Array, pitch: Array) -> Array:
    """Heel, big toe, small toe (N, 3, 3) in the world."""
    return ankle[:, None, :] + foot_to_world(body.foot_local(side), yaw, pitch)


def ankle_on_pivot(
    body: Body, side: int, pivot: Array, pivot_index: int, yaw: Array, pitch: Array
) -> Array:
    """Ankle (N, 3) that puts foot point ``pivot_index`` (0 heel, 1 big toe) on ``pivot``."""
    offset = foot_to_world(body.foot_local(side)[pivot_index : pivot_index + 1], yaw, pitch)
    return pivot - offset[:, 0, :]


# --- inverse and forward kinematics ------------------------------------------


def two_link_ik(root: Array, target: Array, upper: float, lower: float, pole: Array) -> Array:
    """Middle joint (N, 3) of a two-link chain from ``root`` towards ``target``.

    The chain bends towards ``pole`` (N, 3). A target out of reach is pulled
    onto the reachable sphere; lengths are kept exactly. Returns the middle
    joint; the end lies at ``end_of_chain``.
    """
    reach = target - root
    dist = np.linalg.norm(reach, axis=-1, keepdims=True)
    dist_c = np.clip(dist, abs(upper - lower) + 1e-6, upper + lower - 1e-9)
    u = reach / np.maximum(dist, 1e-9)
    along = (upper**2 - lower**2 + dist_c**2) / (2.0 * dist_c)
    across = np.sqrt(np.maximum(upper**2 - along**2, 0.0))
    side = pole - np.sum(pole * u, axis=-1, keepdims=True) * u
    side /= np.maximum(np.linalg.norm(side, axis=-1, keepdims=True), 1e-9)
    return np.asarray(root + along * u + across * side, dtype=np.float64)


def end_of_chain(root: Array, middle: Array, target: Array, lower: float) -> Array:
    """End joint: ``lower`` metres from the middle joint towards the target."""
    d = target - middle
    norm = np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-9)
    return np.asarray(middle + lower * d / norm, dtype=np.float64)


def leg_reach_z(body: Body, hip_xy: Array, ankle: Array, slack: float = 0.999) -> Array:
    """Highest hip z (N,) from which the leg still reaches ``ankle`` (N, 3)."""
    horizontal = np.linalg.norm(hip_xy - ankle[:, :2], axis=-1)
    reach = slack * body.leg
    return np.asarray(ankle[:, 2] + np.sqrt(np.maximum(reach**2 - horizontal**2, 1e-6)))


def hip_points(body: Body, pelvis: Array, heading: Array) -> Array:
    """Left and right hip keypoints (N, 2, 3)."""
    _, left = axes(heading)
    half = 0.5 * body.hip_spacing * left
    return np.stack([pelvis + half, pelvis - half], axis=1)


def pose_keypoints(body: Body, p: PoseParams) -> Array:
    """Forward kinematics: the 19 keypoints (N, 19, 3) in the world frame."""
    n = len(p)
    k = np.zeros((n, NUM_KEYPOINTS, 3))
    up = np.array([0.0, 0.0, 1.0])
    forward, left = axes(p.heading)
    hips = hip_points(body, p.pelvis, p.heading)
    for side, name in enumerate(SIDES):
        hip, ankle_target = hips[:, side], p.ankle[:, side]
        pole, _ = axes(p.foot_yaw[:, side])
        knee = two_link_ik(hip, ankle_target, body.thigh, body.shank, pole + 0.3 * forward)
        ankle = end_of_chain(hip, knee, ankle_target, body.shank)
        feet = foot_points(body, side, ankle, p.foot_yaw[:, side], p.foot_pitch[:, side])
        k[:, KP[f"{name}_hip"]] = hip
        k[:, KP[f"{name}_knee"]] = knee
        k[:, KP[f"{name}_ankle"]] = ankle
        k[:, KP[f"{name}_heel"]] = feet[:, 0]
        k[:, KP[f"{name}_big_toe"]] = feet[:, 1]
        k[:, KP[f"{name}_small_toe"]] = feet[:, 2]
    # Trunk: a rigid line from the mid-hip, leaning forwards by ``lean``.
    c, s = np.cos(p.lean)[:, None], np.sin(p.lean)[:, None]
    trunk_up = c * up + s * forward
    trunk_forward = c * forward - s * up
    neck = p.pelvis + body.trunk * trunk_up
    head_c, head_s = np.cos(0.5 * p.lean)[:, None], np.sin(0.5 * p.lean)[:, None]
    head_up = head_c * up + head_s * forward
    head_forward = head_c * forward - head_s * up
    k[:, KP["nose"]] = neck + body.nose_up * head_up + body.nose_forward * head_forward
    for side, name in enumerate(SIDES):
        outward = left if side == LEFT else -left
        shoulder = neck + 0.5 * body.shoulder_spacing * outward
        flex = p.shoulder_flex[:, side][:, None]
        elbow = shoulder + body.upper_arm * _arm_direction(flex, trunk_up, trunk_forward, outward)
        bend = flex + p.elbow_flex[:, side][:, None]
        wrist = elbow + body.forearm * _arm_direction(bend, trunk_up, trunk_forward, outward)
        k[:, KP[f"{name}_shoulder"]] = shoulder
        k[:, KP[f"{name}_elbow"]] = elbow
        k[:, KP[f"{name}_wrist"]] = wrist
    return k


def _arm_direction(flex: Array, trunk_up: Array, trunk_forward: Array, outward: Array) -> Array:
    """Unit vector of an arm segment swung forwards by ``flex`` from hanging down."""
    ca, sa = np.cos(ARM_ABDUCTION), np.sin(ARM_ABDUCTION)
    swung = -np.cos(flex) * trunk_up + np.sin(flex) * trunk_forward
    return np.asarray(ca * swung + sa * outward, dtype=np.float64)


def center_of_mass(body: Body, k: Array) -> Array:
    """Segment-mass weighted centre of mass (N, 3) of keypoints (N, 19, 3)."""
    neck = 0.5 * (k[:, KP["left_shoulder"]] + k[:, KP["right_shoulder"]])
    mid_hip = 0.5 * (k[:, KP["left_hip"]] + k[:, KP["right_hip"]])
    share, at = MASS_TRUNK_HEAD_NECK
    total = share * (mid_hip + at * (neck - mid_hip))
    for name in SIDES:
        hip, knee, ankle = (k[:, KP[f"{name}_{j}"]] for j in ("hip", "knee", "ankle"))
        shoulder, elbow, wrist = (k[:, KP[f"{name}_{j}"]] for j in ("shoulder", "elbow", "wrist"))
        toes = 0.5 * (k[:, KP[f"{name}_big_toe"]] + k[:, KP[f"{name}_small_toe"]])
        heel = k[:, KP[f"{name}_heel"]]
        metatarsals = heel + 0.75 * (toes - heel)
        forearm_dir = (wrist - elbow) / body.forearm
        hand_end = wrist + body.hand * forearm_dir
        for (m, c), a, b in (
            (MASS_THIGH, hip, knee),
            (MASS_SHANK, knee, ankle),
            (MASS_FOOT, ankle, metatarsals),
            (MASS_UPPER_ARM, shoulder, elbow),
            (MASS_FOREARM, elbow, wrist),
            (MASS_HAND, wrist, hand_end),
        ):
            total = total + m * (a + c * (b - a))
    return np.asarray(total, dtype=np.float64)
