"""Skeleton: proportions of height, rigid bones, IK, centre of mass, pose frame."""

from __future__ import annotations

import numpy as np
import pytest
from scotti.models.contract import KP
from scotti.sim.actions import RECIPES, ActionSpec, Context, Place
from scotti.sim.actions.base import neutral
from scotti.sim.motion import Motion, Subject
from scotti.sim.scene import motion_from_segments
from scotti.sim.skeleton import (
    Body,
    center_of_mass,
    end_of_chain,
    pose_keypoints,
    two_link_ik,
)

# Bones whose length the table in skeleton.py fixes as a share of height.
PROPORTIONAL = {
    ("left_hip", "left_knee"): 0.245,
    ("right_hip", "right_knee"): 0.245,
    ("left_knee", "left_ankle"): 0.246,
    ("right_knee", "right_ankle"): 0.246,
    ("left_shoulder", "left_elbow"): 0.186,
    ("right_shoulder", "right_elbow"): 0.186,
    ("left_elbow", "left_wrist"): 0.146,
    ("right_elbow", "right_wrist"): 0.146,
    ("left_hip", "right_hip"): 0.5 * 0.191,
    ("left_shoulder", "right_shoulder"): 0.8 * 0.259,
}
# Every pair that belongs to one rigid segment (lengths constant over time).
RIGID = [
    *PROPORTIONAL,
    ("left_ankle", "left_heel"),
    ("left_heel", "left_big_toe"),
    ("left_heel", "left_small_toe"),
    ("left_big_toe", "left_small_toe"),
    ("right_ankle", "right_heel"),
    ("right_heel", "right_big_toe"),
    ("right_big_toe", "right_small_toe"),
    ("left_shoulder", "nose"),
]


def _lengths(k: np.ndarray, a: str, b: str) -> np.ndarray:
    return np.asarray(np.linalg.norm(k[:, KP[a]] - k[:, KP[b]], axis=-1))


def _motion(height: float, action: str, heading: float = 0.0) -> Motion:
    subject = Subject(height, 70.0, style_seed=4)
    body = Body.from_height(height, subject.foot_length)
    ctx = Context(body, subject, 16.0, np.random.default_rng(0))
    segment = RECIPES[action](ctx, ActionSpec(action, reps=3), Place(0.3, -0.2, heading))
    return motion_from_segments(body, subject, 16.0, [segment])


def test_body_segments_are_the_tabled_shares_of_height() -> None:
    body = Body.from_height(1.80)
    assert body.thigh == pytest.approx(0.245 * 1.80)
    assert body.shank == pytest.approx(0.246 * 1.80)
    assert body.foot_length == pytest.approx(0.152 * 1.80)
    assert body.foot_height == pytest.approx(0.039 * 1.80)
    assert body.upper_arm == pytest.approx(0.186 * 1.80)
    assert body.forearm == pytest.approx(0.146 * 1.80)
    assert body.trunk == pytest.approx((0.818 - 0.530) * 1.80)
    assert body.stand_hip_z == pytest.approx(0.530 * 1.80)
    assert Body.from_height(1.8, foot_length=0.25).foot_length == 0.25


@pytest.mark.parametrize(("height", "action"), [(1.55, "walking"), (1.92, "lunge")])
def test_bones_equal_proportions_and_stay_rigid_over_a_motion(height: float, action: str) -> None:
    k = _motion(height, action).world
    for (a, b), share in PROPORTIONAL.items():
        length = _lengths(k, a, b)
        assert np.abs(length - share * height).max() < 1e-3, (a, b)
    for a, b in RIGID:
        length = _lengths(k, a, b)
        assert np.ptp(length) < 1e-3, (a, b)
    heel_to_toe = _lengths(k, "left_heel", "left_big_toe")
    assert heel_to_toe.mean() == pytest.approx(0.152 * height, rel=0.03)


def test_two_link_ik_reaches_a_reachable_target_and_bends_towards_the_pole() -> None:
    root = np.array([[0.0, 0.0, 1.0]])
    target = np.array([[0.1, 0.0, 0.3]])
    pole = np.array([[1.0, 0.0, 0.0]])
    knee = two_link_ik(root, target, 0.45, 0.42, pole)
    end = end_of_chain(root, knee, target, 0.42)
    assert np.linalg.norm(knee - root) == pytest.approx(0.45)
    assert np.linalg.norm(end - knee) == pytest.approx(0.42)
    np.testing.assert_allclose(end, target, atol=1e-9)
    assert knee[0, 0] > 0.1  # bent forwards, towards the pole
    far = np.array([[0.0, 0.0, -1.0]])  # out of reach: lengths kept, end pulled back
    knee = two_link_ik(root, far, 0.45, 0.42, pole)
    end = end_of_chain(root, knee, far, 0.42)
    assert np.linalg.norm(end - root) == pytest.approx(0.87, abs=1e-6)


def test_standing_centre_of_mass_is_over_the_feet_at_about_055_of_height() -> None:
    body = Body.from_height(1.75)
    p = neutral(body, Place(0.0, 0.0, 0.0), 1)
    k = pose_keypoints(body, p)
    com = center_of_mass(body, k)[0]
    assert 0.53 * 1.75 < com[2] < 0.60 * 1.75
    assert abs(com[0]) < 0.03
    assert abs(com[1]) < 1e-9  # symmetric
    arms_forward = p.replace(shoulder_flex=np.full((1, 2), 1.5))
    moved = center_of_mass(body, pose_keypoints(body, arms_forward))[0]
    assert moved[0] > com[0] + 0.02


def test_pose_frame_puts_mid_hip_at_origin_on_the_floor_facing_x() -> None:
    motion = _motion(1.75, "walking", heading=np.pi / 2)
    pose = motion.pose_frame()
    mid_hip = 0.5 * (pose[:, KP["left_hip"]] + pose[:, KP["right_hip"]])
    np.testing.assert_allclose(mid_hip[:, :2], 0.0, atol=1e-9)
    world_mid = 0.5 * (motion.world[:, KP["left_hip"]] + motion.world[:, KP["right_hip"]])
    np.testing.assert_allclose(mid_hip[:, 2], world_mid[:, 2])
    assert (pose[:, KP["nose"], 0] > 0.0).all()  # facing +x
    assert (pose[:, KP["left_hip"], 1] > 0.0).all()  # left is +y
    assert (pose[:, KP["nose"], 2] > 1.4).all()  # z up
    # Walking at heading 90 degrees goes along world +y.
    assert world_mid[-1, 1] - world_mid[0, 1] > 1.0
