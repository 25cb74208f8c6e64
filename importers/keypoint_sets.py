"""Named keypoint sets and how each maps onto our 19 (models/contract.py KEYPOINTS).

Each set lists its source names in the order the set's tools write them;
``SET_MAPPINGS`` says which of our keypoints each source point is. A
keypoint of ours that a set does not have stays masked (NaN): the importer
never invents one from the others.
"""

from __future__ import annotations

from typing import Final

from scotti.models.contract import KEYPOINTS

# COCO-WholeBody: the 17 COCO body points, then the 6 foot points (then 68
# face and 42 hand points, which we do not use). Our 19 are these without
# eyes and ears, under the same names.
COCO_WHOLEBODY: Final[tuple[str, ...]] = (
    "nose", "left_eye", "right_eye", "left_ear", "right_ear",
    "left_shoulder", "right_shoulder", "left_elbow", "right_elbow",
    "left_wrist", "right_wrist", "left_hip", "right_hip", "left_knee",
    "right_knee", "left_ankle", "right_ankle",
    "left_big_toe", "left_small_toe", "left_heel",
    "right_big_toe", "right_small_toe", "right_heel",
)  # fmt: skip

# MediaPipe Pose (BlazePose), 33 landmarks.
MEDIAPIPE33: Final[tuple[str, ...]] = (
    "nose", "left_eye_inner", "left_eye", "left_eye_outer", "right_eye_inner",
    "right_eye", "right_eye_outer", "left_ear", "right_ear", "mouth_left",
    "mouth_right", "left_shoulder", "right_shoulder", "left_elbow",
    "right_elbow", "left_wrist", "right_wrist", "left_pinky", "right_pinky",
    "left_index", "right_index", "left_thumb", "right_thumb", "left_hip",
    "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle",
    "left_heel", "right_heel", "left_foot_index", "right_foot_index",
)  # fmt: skip

# OpenPose BODY_25.
BODY25: Final[tuple[str, ...]] = (
    "Nose", "Neck", "RShoulder", "RElbow", "RWrist", "LShoulder", "LElbow",
    "LWrist", "MidHip", "RHip", "RKnee", "RAnkle", "LHip", "LKnee", "LAnkle",
    "REye", "LEye", "REar", "LEar", "LBigToe", "LSmallToe", "LHeel",
    "RBigToe", "RSmallToe", "RHeel",
)  # fmt: skip

SETS: Final[dict[str, tuple[str, ...]]] = {
    "coco_wholebody": COCO_WHOLEBODY,
    "mediapipe33": MEDIAPIPE33,
    "body25": BODY25,
}

# our name -> the set's name. MediaPipe's "foot_index" is the tip of the foot
# (between the first and second toe), the nearest it has to a big toe; it has
# no small toe, which therefore stays masked.
SET_MAPPINGS: Final[dict[str, dict[str, str]]] = {
    "coco_wholebody": {name: name for name in KEYPOINTS},
    "mediapipe33": {
        **{name: name for name in KEYPOINTS if name in MEDIAPIPE33},
        "left_big_toe": "left_foot_index",
        "right_big_toe": "right_foot_index",
    },
    "body25": {
        "nose": "Nose",
        "left_shoulder": "LShoulder",
        "right_shoulder": "RShoulder",
        "left_elbow": "LElbow",
        "right_elbow": "RElbow",
        "left_wrist": "LWrist",
        "right_wrist": "RWrist",
        "left_hip": "LHip",
        "right_hip": "RHip",
        "left_knee": "LKnee",
        "right_knee": "RKnee",
        "left_ankle": "LAnkle",
        "right_ankle": "RAnkle",
        "left_big_toe": "LBigToe",
        "left_small_toe": "LSmallToe",
        "left_heel": "LHeel",
        "right_big_toe": "RBigToe",
        "right_small_toe": "RSmallToe",
        "right_heel": "RHeel",
    },
}


def source_index(names: tuple[str, ...], mapping: dict[str, str | int]) -> list[int | None]:
    """For each of our 19 keypoints, its index among ``names`` (None: not mapped)."""
    out: list[int | None] = []
    for ours in KEYPOINTS:
        theirs = mapping.get(ours)
        if theirs is None:
            out.append(None)
        elif isinstance(theirs, int):
            out.append(theirs)
        else:
            out.append(names.index(theirs) if theirs in names else -1)
    return out
