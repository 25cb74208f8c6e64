"""Keypoints: named sets, custom mappings, a camera frame with y down, the pose frame."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scotti.importers.config import ImportConfig, KeypointsConfig, config_from_dict
from scotti.importers.errors import InputError
from scotti.importers.keypoint_sets import BODY25, COCO_WHOLEBODY, MEDIAPIPE33, SET_MAPPINGS
from scotti.importers.pose import pose_frame, read_keypoints, to_world, up_rotation
from scotti.models.contract import KEYPOINTS, KP

from tests.support.foreign import in_set, squat_pose, to_camera, write_keypoints_csv


def config(folder: Path, keypoints: dict[str, object]) -> ImportConfig:
    raw = {
        "pressure": {"file": "p.npz", "rows": 2, "cols": 2},
        "keypoints": keypoints,
        "base_dir": str(folder),
    }
    return config_from_dict(raw)


def test_every_named_set_maps_only_names_it_has() -> None:
    for name, names in (("coco_wholebody", COCO_WHOLEBODY), ("mediapipe33", MEDIAPIPE33)):
        assert set(SET_MAPPINGS[name].values()) <= set(names)
    assert set(SET_MAPPINGS["body25"].values()) <= set(BODY25)
    assert sorted(SET_MAPPINGS["body25"]) == sorted(KEYPOINTS)  # BODY_25 has all 19
    assert "left_small_toe" not in SET_MAPPINGS["mediapipe33"]  # MediaPipe has none


def keypoints_of(cfg: ImportConfig) -> KeypointsConfig:
    assert cfg.keypoints is not None
    return cfg.keypoints


@pytest.mark.parametrize("up", [(0, 0, 1), (0, -1, 0), (1, 1, 1), (0, 0, -1)])
def test_up_rotation_is_proper_and_points_up(up: tuple[float, float, float]) -> None:
    r = up_rotation(np.array(up, dtype=float))
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)
    np.testing.assert_allclose(r @ (np.array(up) / np.linalg.norm(up)), [0, 0, 1], atol=1e-12)


def test_camera_frame_with_y_down_comes_back_in_the_pose_frame(tmp_path: Path) -> None:
    t = np.arange(0, 4, 1 / 30)
    pose = squat_pose(t)
    camera = to_camera(pose, heading=2.0) * 1000.0  # millimetres
    write_keypoints_csv(tmp_path / "k.csv", t, in_set(camera, "mediapipe33"), MEDIAPIPE33)
    cfg = config(tmp_path, {"file": "k.csv", "set": "mediapipe33", "up": "-y", "units": "mm"})
    source = read_keypoints(cfg)
    assert "left_small_toe" not in source.mapped
    ours = pose_frame(to_world(keypoints_of(cfg), source))
    have = [KP[name] for name in source.mapped]
    np.testing.assert_allclose(ours[:, have], pose[:, have], atol=1e-5)  # CSV: 6 digits of mm
    assert np.isnan(ours[:, KP["left_small_toe"]]).all()  # masked, not invented


def test_up_auto_and_a_custom_smaller_set(tmp_path: Path) -> None:
    t = np.arange(0, 2, 1 / 25)
    pose = squat_pose(t)
    keep = ["left_hip", "right_hip", "left_shoulder", "right_shoulder", "left_ankle"]
    keep += ["right_ankle", "left_heel", "right_heel", "left_big_toe", "right_big_toe"]
    names = [f"m{i}" for i in range(len(keep))]
    camera = to_camera(pose)[:, [KP[k] for k in keep]]
    np.savez(tmp_path / "k.npz", time=t, keypoints=camera, names=np.array(names))
    mapping = dict(zip(keep, names, strict=True))
    cfg = config(tmp_path, {"file": "k.npz", "set": "custom", "mapping": mapping, "up": "auto"})
    source = read_keypoints(cfg)
    ours = pose_frame(to_world(keypoints_of(cfg), source))
    have = [KP[k] for k in keep]
    # "auto" takes up from ankles to shoulders: the template leans a little, so
    # the result is close, not exact.
    np.testing.assert_allclose(ours[:, have], pose[:, have], atol=0.02)
    missing = sorted(set(range(19)) - set(have))
    assert np.isnan(ours[:, missing]).all()


def test_a_mapping_to_a_name_the_file_lacks(tmp_path: Path) -> None:
    t = np.arange(5) / 10
    np.savez(tmp_path / "k.npz", time=t, keypoints=np.zeros((5, 2, 3)), names=np.array(["a", "b"]))
    cfg = config(tmp_path, {"file": "k.npz", "set": "custom", "mapping": {"nose": "c"}})
    with pytest.raises(InputError, match=r"k\.npz: no keypoint 'c' for nose"):
        read_keypoints(cfg)


def test_a_mirrored_source_is_refused_and_mirror_fixes_it(tmp_path: Path) -> None:
    t = np.arange(0, 2, 1 / 30)
    pose = squat_pose(t)
    camera = to_camera(pose)
    camera[..., 0] *= -1.0  # a mirrored video: left and right swap sides
    write_keypoints_csv(tmp_path / "k.csv", t, in_set(camera, "body25"), BODY25)
    keypoints = {"file": "k.csv", "set": "body25", "up": "-y"}
    cfg = config(tmp_path, keypoints)
    source = read_keypoints(cfg)
    with pytest.raises(InputError, match=r"mirrored.*set mirror = true"):
        to_world(keypoints_of(cfg), source)
    fixed = config(tmp_path, {**keypoints, "mirror": True})
    ours = pose_frame(to_world(keypoints_of(fixed), read_keypoints(fixed)))
    np.testing.assert_allclose(ours, pose, atol=1e-5)


def write_scored_csv(path: Path, pose: np.ndarray, columns: dict[str, np.ndarray]) -> None:
    """COCO-WholeBody names, x y z per point, then each extra ``NAME_suffix`` column given."""
    t = np.arange(pose.shape[0]) / 30
    header = ["time"] + [f"{n}_{a}" for n in KEYPOINTS for a in "xyz"] + list(columns)
    extra = np.column_stack(list(columns.values())) if columns else np.empty((t.size, 0))
    body = np.column_stack([t, pose.reshape(t.size, -1), extra])
    lines = [",".join(header)] + [",".join(f"{v:.6g}" for v in row) for row in body]
    path.write_text("\n".join(lines) + "\n")


def test_mediapipe_visibility_is_read_as_a_score(tmp_path: Path) -> None:
    pose = squat_pose(np.arange(0, 1, 1 / 30))
    low = np.where(np.arange(30) % 3 == 0, 0.2, 0.95)  # the left knee hidden in every third frame
    write_scored_csv(tmp_path / "k.csv", pose, {"left_knee_visibility": low})
    cfg = config(tmp_path, {"file": "k.csv", "set": "coco_wholebody", "min_score": 0.5})
    points = read_keypoints(cfg).points
    hidden = np.isnan(points[:, KP["left_knee"]]).all(axis=1)
    np.testing.assert_array_equal(hidden, low < 0.5)
    assert np.isfinite(np.delete(points, KP["left_knee"], axis=1)).all()


def test_a_score_column_wins_over_visibility(tmp_path: Path) -> None:
    pose = squat_pose(np.arange(0, 1, 1 / 30))
    score = np.where(np.arange(30) < 10, 0.1, 0.9)
    visibility = np.where(np.arange(30) < 20, 0.9, 0.1)
    columns = {"nose_score": score, "nose_visibility": visibility}
    write_scored_csv(tmp_path / "k.csv", pose, columns)
    cfg = config(tmp_path, {"file": "k.csv", "set": "coco_wholebody", "min_score": 0.5})
    hidden = np.isnan(read_keypoints(cfg).points[:, KP["nose"]]).all(axis=1)
    np.testing.assert_array_equal(hidden, score < 0.5)


def test_floor_from_the_feet_needs_heels_or_toes(tmp_path: Path) -> None:
    t = np.arange(0, 2, 1 / 25)
    keep = ["left_hip", "right_hip", "left_shoulder", "right_shoulder", "left_ankle", "right_ankle"]
    camera = to_camera(squat_pose(t))[:, [KP[k] for k in keep]]
    np.savez(tmp_path / "k.npz", time=t, keypoints=camera, names=np.array(keep))
    mapping = {k: k for k in keep}
    keypoints = {"file": "k.npz", "set": "custom", "mapping": mapping, "up": "-y"}
    cfg = config(tmp_path, {**keypoints, "floor": "feet"})
    with pytest.raises(InputError, match=r"k\.npz: floor = 'feet' needs heels or toes"):
        to_world(keypoints_of(cfg), read_keypoints(cfg))


def test_floor_z_belongs_to_one_floor_plane(tmp_path: Path) -> None:
    with pytest.raises(
        InputError, match=r"keypoints: .*floor_z is the one floor of floor = 'plane'"
    ):
        config(tmp_path, {"file": "k.csv", "set": "body25", "floor": "feet", "floor_z": 0.0})


def test_a_frame_with_no_heel_or_toe_seen_has_no_floor(tmp_path: Path) -> None:
    t = np.arange(0, 2, 1 / 30)
    pose = squat_pose(t)
    camera = in_set(to_camera(pose), "body25")
    feet = [i for i, name in enumerate(BODY25) if name[1:] in ("BigToe", "SmallToe", "Heel")]
    camera[5][feet] = np.nan  # frame 5: no foot point on the floor seen
    write_keypoints_csv(tmp_path / "k.csv", t, camera, BODY25)
    cfg = config(tmp_path, {"file": "k.csv", "set": "body25", "up": "-y", "floor": "feet"})
    ours = pose_frame(to_world(keypoints_of(cfg), read_keypoints(cfg)))
    assert np.isnan(ours[5]).all()
    others = np.delete(np.arange(t.size), 5)
    np.testing.assert_allclose(ours[others], pose[others], atol=1e-5)
