"""Floating keypoints (MediaPipe's hip-centred world landmarks): refused, or stood on their feet.

A simulated session is written out as MediaPipe would write it (33 world
landmarks with visibility; experiments/keypoints_floor.py), with its
pressure and actions, and imported back with ``scotti import``; the
imported keypoints are compared with the simulator's truth.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from scotti.models.contract import ACTIONS, KP

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "experiments"))

import keypoints_floor as kf  # noqa: E402

SCENES = ROOT / "sim" / "scenes"


def exported(folder: Path, scene: str) -> kf.Truth:
    return kf.export(kf.simulate(SCENES / scene, folder / "truth.scotti"), folder, noise_mm=0.0)


@pytest.fixture(scope="module")
def squats(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, kf.Truth]:
    folder = tmp_path_factory.mktemp("squats")
    return folder, exported(folder, "squat.toml")


def test_a_kept_folder_is_measured_again(tmp_path: Path) -> None:
    truth = tmp_path / "truth.scotti"
    truth.write_bytes(b"the first call's file")
    # --keep DIR a second time: the scene is simulated anew over the first call's file.
    assert kf.simulate(SCENES / "squat.toml", truth) == truth
    assert kf.truth_of(truth)[0].times.size > 0


def squat_mpjpe_mm(ours: np.ndarray, truth: kf.Truth) -> float:
    squat = truth.action == ACTIONS.index("squat")
    return float(np.nanmean(kf.per_frame_error(ours, truth.keypoints)[squat]) * 1000)


def test_hip_centred_landmarks_are_refused_with_the_option_that_fixes_them(
    squats: tuple[Path, kf.Truth],
) -> None:
    folder, _ = squats
    rc, err = kf.run_import(kf.import_args(folder, "hip-centred.csv", None), folder / "a.scotti")
    assert rc == 2
    assert err.count("\n") == 0  # one line
    assert err.startswith(f"scotti import: {folder / 'hip-centred.csv'}: ")
    assert "mid-hip keeps within 0 mm of one height" in err
    assert 'floor = "feet" (--floor feet)' in err
    assert not (folder / "a.scotti").exists()
    # The same landmarks on the camera's fixed frame stand on a floor: imported as they are.
    rc, err = kf.run_import(kf.import_args(folder, "camera.csv", None), folder / "b.scotti")
    assert (rc, err) == (0, "")


def test_floor_from_the_feet_recovers_squats(squats: tuple[Path, kf.Truth]) -> None:
    # During a squat a foot is always on the floor, so standing each frame on its
    # lowest heel or toe puts the hips where a fixed camera saw them: the bound is
    # the camera frame's own error (the importer's facing estimate, 1.0 mm) plus 1 mm.
    # Imported as they are, the hips never sink and the error is 153 mm.
    folder, truth = squats
    rc, _ = kf.run_import(kf.import_args(folder, "camera.csv", None), folder / "camera.scotti")
    assert rc == 0
    camera, camera_progress = kf.imported(folder / "camera.scotti", truth)
    rc, err = kf.run_import(kf.import_args(folder, "hip-centred.csv", "feet"), folder / "f.scotti")
    assert (rc, err) == (0, "")
    feet, feet_progress = kf.imported(folder / "f.scotti", truth)
    bound = squat_mpjpe_mm(camera, truth) + 1.0
    assert squat_mpjpe_mm(feet, truth) < bound
    as_they_are = kf.as_is(folder)  # what the check refuses
    assert squat_mpjpe_mm(as_they_are, truth) > 10 * bound
    # Progress comes from the hips' height: where the truth has it, so does the import.
    squat = truth.action == ACTIONS.index("squat")
    labelled = squat & np.isfinite(truth.progress)
    assert labelled.sum() > 200
    np.testing.assert_array_equal(np.isfinite(feet_progress), np.isfinite(camera_progress))
    assert np.abs(feet_progress - truth.progress)[labelled].max() < 0.01


def test_a_flight_or_a_step_looks_like_standing_on_the_floor(tmp_path: Path) -> None:
    # What floor = "feet" cannot see: with both feet in the air (a jump) or on a
    # step, the lowest foot is put on the floor, so the whole body comes down by
    # that foot's true height; wherever a foot is on the floor, nothing is lost.
    truth = exported(tmp_path, "all-actions.toml")
    rc, _ = kf.run_import(
        kf.import_args(tmp_path, "hip-centred.csv", "feet"), tmp_path / "f.scotti"
    )
    assert rc == 0
    ours, _ = kf.imported(tmp_path / "f.scotti", truth)
    lowest = kf.lowest_foot(truth.keypoints)
    raised = lowest > kf.RAISED_M
    kinds = {ACTIONS[a] for a in truth.action[raised]}
    assert kinds == {"jump", "step_up"}
    hip = [KP["left_hip"], KP["right_hip"]]
    ours_hip = ours[:, hip, 2].mean(axis=1)
    truth_hip = truth.keypoints[:, hip, 2].mean(axis=1)
    np.testing.assert_allclose(ours_hip, truth_hip - lowest, atol=0.002)
    on_floor = lowest < 0.001
    assert on_floor.mean() > 0.9
    np.testing.assert_allclose(ours_hip[on_floor], truth_hip[on_floor], atol=0.002)
    assert (truth_hip - ours_hip)[raised].max() > 0.15  # a real loss, not a rounding


def write_like_camera(folder: Path, name: str, shift: np.ndarray) -> None:
    """camera.csv with each frame's landmarks moved by ``shift`` (N, 3) camera metres."""
    lines = (folder / "camera.csv").read_text().splitlines()
    header = lines[0].split(",")
    values = np.array([[float(v) for v in line.split(",")] for line in lines[1:]])
    for axis, suffix in enumerate(("_x", "_y", "_z")):
        cols = [i for i, h in enumerate(header) if h.endswith(suffix)]
        values[:, cols] += shift[:, axis : axis + 1]
    body = [f"{row[0]:.9f}," + ",".join(f"{v:.9g}" for v in row[1:]) for row in values]
    (folder / name).write_text("\n".join([lines[0], *body]) + "\n")


def test_an_origin_that_jumps_about_is_refused_and_the_feet_fix_it(
    squats: tuple[Path, kf.Truth],
) -> None:
    # A tracker that estimates the person's distance afresh each frame: the whole
    # body moves up and down at random, so no torso point keeps to one height, but
    # the feet are seldom on any one floor.
    folder, truth = squats
    rng = np.random.default_rng(3)
    shift = np.zeros((truth.times.size, 3))
    shift[:, 1] = rng.uniform(-0.5, 0.5, truth.times.size)  # camera y: down
    write_like_camera(folder, "jumpy.csv", shift)
    rc, err = kf.run_import(kf.import_args(folder, "jumpy.csv", None), folder / "j.scotti")
    assert rc == 2
    assert "the lowest foot is within 100 mm of one floor in only" in err
    assert 'floor = "feet" (--floor feet)' in err
    rc, _ = kf.run_import(kf.import_args(folder, "jumpy.csv", "feet"), folder / "j.scotti")
    assert rc == 0
    ours, _ = kf.imported(folder / "j.scotti", truth)
    assert squat_mpjpe_mm(ours, truth) < 5.0


def test_shoulder_centred_landmarks_are_refused_too(squats: tuple[Path, kf.Truth]) -> None:
    folder, truth = squats
    camera = kf.to_camera(truth.keypoints)
    mid_shoulder = 0.5 * (camera[:, KP["left_shoulder"]] + camera[:, KP["right_shoulder"]])
    write_like_camera(folder, "shoulders.csv", -mid_shoulder)
    rc, err = kf.run_import(kf.import_args(folder, "shoulders.csv", None), folder / "s.scotti")
    assert rc == 2
    assert "the keypoints float with the body" in err
