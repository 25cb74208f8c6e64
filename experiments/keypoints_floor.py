"""MediaPipe keypoints of a simulated session, imported with its pressure: how far from the truth.

    python experiments/keypoints_floor.py [SCENES...] [--noise-mm 0] [--keep DIR]

Each scene (default: sim/scenes/squat.toml and sim/scenes/all-actions.toml)
is simulated, and its ground-truth pose is written out as MediaPipe Pose
would write it: 33 world landmarks a frame, metres, in the camera's axes (x
right, y down, z away from the camera), with ``NAME_visibility``, the person
turned 35 degrees from the camera. The pressure goes out as counts (.npz),
the actions as a segment file. Then ``scotti import`` brings them back, and
the imported keypoints and progress are compared with the truth, frame by
frame (MPJPE over the 17 keypoints MediaPipe has, mm; progress mean absolute
error), overall and per action. Rows:

- ``camera``: the landmarks on the camera's fixed frame (a person standing on
  a floor 1.2 m below the camera): the control, default options;
- ``hip-centred``: MediaPipe's world landmarks as they are, origin between
  the hips, default options (the import refuses them; the figures are what the
  importer's functions give without that check, as before it existed);
- ``hip-centred, floor = feet``: the same file with ``--floor feet``.

Beside each action, the frames where the truth's lowest foot is more than
1 cm above the floor: a jump's flight, a step-up on the step.

``--noise-mm`` adds Gaussian noise of that standard deviation to every
landmark coordinate (a tracker's jitter); the truth stays clean.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scotti.cli.main import main as scotti
from scotti.export.data import decode_session
from scotti.firmware_protocol.session import read_session
from scotti.importers.config import load_config
from scotti.importers.keypoint_sets import MEDIAPIPE33, SET_MAPPINGS
from scotti.importers.pose import pose_frame, read_keypoints, to_world
from scotti.models.contract import ACTIONS, KEYPOINTS, KP, NO_ACTION

ROOT = Path(__file__).resolve().parent.parent
SCENES = (ROOT / "sim" / "scenes" / "squat.toml", ROOT / "sim" / "scenes" / "all-actions.toml")
HEADING_RAD = np.deg2rad(35.0)  # the person's facing, turned from the camera's line of sight
CAMERA_HEIGHT_M = 1.2
CAMERA_DISTANCE_M = 3.0
VISIBILITY = 0.99
FRAME_S = 1.0 / 16.0
RAISED_M = 0.01  # the lowest foot this high: in the air, or on the step


@dataclass(frozen=True)
class Truth:
    times: np.ndarray  # (N,) seconds from the session's first frame
    keypoints: np.ndarray  # (N, 19, 3) pose frame, metres
    action: np.ndarray  # (N,) int64
    progress: np.ndarray  # (N,) float32, NaN where none


def simulate(scene: Path, out: Path) -> Path:
    with contextlib.redirect_stdout(io.StringIO()):
        # --force: with --keep a second call measures again, the scene made anew.
        assert scotti(["sim", str(scene), "-o", str(out), "--force"]) == 0
    return out


def truth_of(session: Path) -> tuple[Truth, np.ndarray]:
    """The session's labels and its counts (N, 2, 32, 22), one row per labelled frame."""
    labels = sorted(read_session(session).labels, key=lambda lab: lab.seq)
    arrays = decode_session(session)
    index = {int(s): i for i, s in enumerate(arrays.seq)}
    width = arrays.frames.shape[2] // 2
    rows = [index[lab.seq] for lab in labels]
    frames = arrays.frames[rows]
    counts = np.stack([frames[:, :, :width], frames[:, :, width:]], axis=1)
    t_ns = np.array([lab.t_ns for lab in labels], dtype=np.int64)
    truth = Truth(
        # From the first frame: the frame times are then exact in binary (k / 16 s)
        # and in the CSV's nine decimals, so both files hold the same times.
        times=(t_ns - t_ns[0]) * 1e-9,
        keypoints=np.stack([lab.keypoints for lab in labels]).astype(np.float64),
        action=np.array([lab.action for lab in labels], dtype=np.int64),
        progress=np.array([lab.progress for lab in labels], dtype=np.float32),
    )
    return truth, counts


def mediapipe_landmarks(pose: np.ndarray) -> np.ndarray:
    """(N, 19, 3) pose frame -> (N, 33, 3) MediaPipe's landmarks, same frame.

    The 17 it shares with ours are ours; the face and hand points it adds
    are put a few centimetres from the nose and the wrists (the importer
    does not use them; they are there so that the file looks like one).
    """
    inverse = {theirs: mine for mine, theirs in SET_MAPPINGS["mediapipe33"].items()}
    out = np.zeros((pose.shape[0], len(MEDIAPIPE33), 3))
    nose = pose[:, KP["nose"]]
    face = {"eye_inner": (0.0, 0.015, 0.03), "eye": (-0.005, 0.03, 0.03)}
    face |= {"eye_outer": (-0.01, 0.045, 0.03), "ear": (-0.08, 0.07, 0.0)}
    for i, name in enumerate(MEDIAPIPE33):
        if name in inverse:
            out[:, i] = pose[:, KP[inverse[name]]]
            continue
        side, _, part = name.partition("_")
        sign = 1.0 if side == "left" else -1.0
        if part in face:
            dx, dy, dz = face[part]
            out[:, i] = nose + np.array([dx, sign * dy, dz])
        elif side == "mouth":
            out[:, i] = nose + np.array([0.0, (1.0 if part == "left" else -1.0) * 0.025, -0.04])
        else:  # pinky, index, thumb: past the wrist, along the forearm
            wrist, elbow = pose[:, KP[f"{side}_wrist"]], pose[:, KP[f"{side}_elbow"]]
            along = {"pinky": 0.07, "index": 0.08, "thumb": 0.05}[part]
            out[:, i] = wrist + along * (wrist - elbow) / 0.27
    return out


def to_camera(pose: np.ndarray) -> np.ndarray:
    """Pose frame -> the camera's axes: x right, y down, z away; floor 1.2 m below it."""
    c, s = np.cos(HEADING_RAD), np.sin(HEADING_RAD)
    x = c * pose[..., 0] - s * pose[..., 1]
    y = s * pose[..., 0] + c * pose[..., 1]
    return np.stack([-y, CAMERA_HEIGHT_M - pose[..., 2], x + CAMERA_DISTANCE_M], axis=-1)


def write_mediapipe_csv(
    path: Path, times: np.ndarray, landmarks: np.ndarray, visibility: np.ndarray
) -> None:
    """``time, NAME_x, NAME_y, NAME_z, NAME_visibility`` per landmark, one line a frame."""
    header = ["time"] + [f"{n}_{a}" for n in MEDIAPIPE33 for a in ("x", "y", "z", "visibility")]
    cells = np.concatenate([landmarks, visibility[..., None]], axis=2).reshape(times.size, -1)
    rows = (
        f"{t:.9f}," + ",".join(f"{v:.9g}" for v in row) for t, row in zip(times, cells, strict=True)
    )
    lines = [",".join(header), *rows]
    path.write_text("\n".join(lines) + "\n")


def write_segments(path: Path, truth: Truth) -> None:
    """One segment per run of an action, seconds from the first frame."""
    a = truth.action
    starts = np.flatnonzero(np.r_[True, a[1:] != a[:-1]])
    ends = np.r_[starts[1:], a.size] - 1
    lines = ["start,end,action"]
    t0 = truth.times[0]
    for s, e in zip(starts.tolist(), ends.tolist(), strict=True):
        if a[s] != NO_ACTION:
            start, end = truth.times[s] - t0, truth.times[e] - t0 + FRAME_S / 2
            lines.append(f"{start:.6f},{end:.6f},{ACTIONS[a[s]]}")
    path.write_text("\n".join(lines) + "\n")


def export(session: Path, folder: Path, noise_mm: float, seed: int = 0) -> Truth:
    """pressure.npz, segments.csv, camera.csv and hip-centred.csv of a simulated session."""
    truth, counts = truth_of(session)
    np.savez(folder / "pressure.npz", time=truth.times, left=counts[:, 0], right=counts[:, 1])
    write_segments(folder / "segments.csv", truth)
    landmarks = to_camera(mediapipe_landmarks(truth.keypoints))
    rng = np.random.default_rng(seed)
    landmarks = landmarks + rng.normal(0.0, noise_mm / 1000.0, landmarks.shape)
    visibility = np.full(landmarks.shape[:2], VISIBILITY)
    write_mediapipe_csv(folder / "camera.csv", truth.times, landmarks, visibility)
    hips = [MEDIAPIPE33.index("left_hip"), MEDIAPIPE33.index("right_hip")]
    centred = landmarks - landmarks[:, hips].mean(axis=1, keepdims=True)
    write_mediapipe_csv(folder / "hip-centred.csv", truth.times, centred, visibility)
    return truth


def import_args(folder: Path, keypoints: str, floor: str | None) -> list[str]:
    args = ["import", "--pressure", str(folder / "pressure.npz"), "--grid", "32x22"]
    args += ["--gain", "1", "--keypoints", str(folder / keypoints)]
    args += ["--keypoint-set", "mediapipe33", "--up=-y", "--segments", str(folder / "segments.csv")]
    return args + ([] if floor is None else ["--floor", floor])


def run_import(args: list[str], out: Path) -> tuple[int, str]:
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        rc = scotti([*args, "-o", str(out), "--force"])
    return rc, err.getvalue().strip()


def imported(out: Path, truth: Truth) -> tuple[np.ndarray, np.ndarray]:
    """The imported session's keypoints and progress on the truth's frames (NaN: none)."""
    labels = {round(lab.t_ns * 1e-9 / FRAME_S): lab for lab in read_session(out).labels}
    keypoints = np.full_like(truth.keypoints, np.nan)
    progress = np.full(truth.times.size, np.nan)
    for i, t in enumerate(truth.times):
        lab = labels.get(round(t / FRAME_S))
        if lab is not None:
            keypoints[i] = lab.keypoints
            progress[i] = lab.progress
    return keypoints, progress


def as_is(folder: Path) -> np.ndarray:
    """The hip-centred file through the importer's pose steps without the floating check."""
    (folder / "as-is.toml").write_text(
        '[pressure]\nfile = "pressure.npz"\nrows = 32\ncols = 22\n'
        '[keypoints]\nfile = "hip-centred.csv"\nset = "mediapipe33"\nup = "-y"\n'
    )
    cfg = load_config(folder / "as-is.toml")
    assert cfg.keypoints is not None
    return pose_frame(to_world(cfg.keypoints, read_keypoints(cfg), refuse_floating=False))


def per_frame_error(ours: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(N,) mean distance (m) over the keypoints both have; NaN where none."""
    d = np.linalg.norm(ours - truth, axis=2)
    seen = np.isfinite(d)
    return np.where(seen.any(axis=1), np.nansum(d, axis=1) / np.maximum(seen.sum(1), 1), np.nan)


def per_frame_height_error(ours: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(N,) mean signed height error (m, ours - truth) over the keypoints both have."""
    dz = ours[..., 2] - truth[..., 2]
    seen = np.isfinite(dz)
    return np.where(seen.any(axis=1), np.nansum(dz, axis=1) / np.maximum(seen.sum(1), 1), np.nan)


@dataclass(frozen=True)
class Row:
    name: str
    error_m: np.ndarray  # (N,) per frame
    height_m: np.ndarray  # (N,) per frame, signed
    progress_error: np.ndarray | None  # (N,) absolute, NaN where either is missing
    note: str = ""


def row(
    name: str, ours: np.ndarray, truth: Truth, progress: np.ndarray | None, note: str = ""
) -> Row:
    error = per_frame_error(ours, truth.keypoints)
    height = per_frame_height_error(ours, truth.keypoints)
    progress_error = None if progress is None else np.abs(progress - truth.progress)
    return Row(name, error, height, progress_error, note)


def table(truth: Truth, rows: list[Row]) -> str:
    groups = [("all", np.ones(truth.times.size, bool))]
    for a in sorted(set(truth.action.tolist()) - {NO_ACTION}):
        groups.append((ACTIONS[a], truth.action == a))
    raised = lowest_foot(truth.keypoints) > RAISED_M
    for action, name in (("jump", "jump: in flight"), ("step_up", "step_up: on the step")):
        where = raised & (truth.action == ACTIONS.index(action))
        if where.any():
            groups.append((name, where))
    w = [max(len(g) + 2, 8) for g, _ in groups]
    head = f"{'':36s}" + "".join(f"{g:>{n}s}" for (g, _), n in zip(groups, w, strict=True))
    count = "".join(f"{int(m.sum()):>{n}d}" for (_, m), n in zip(groups, w, strict=True))
    lines = [head, f"{'frames':36s}" + count]
    for r in rows:
        if r.note:
            lines.append(f"{r.name:36s}{r.note}")
        cells = [np.nanmean(r.error_m[m]) * 1000 if m.any() else np.nan for _, m in groups]
        shown = "".join(f"{c:{n}.1f}" for c, n in zip(cells, w, strict=True))
        lines.append(f"{r.name + ' MPJPE mm':36s}" + shown)
        cells = [np.nanmean(r.height_m[m]) * 1000 if m.any() else np.nan for _, m in groups]
        shown = "".join(f"{c:{n}.1f}" for c, n in zip(cells, w, strict=True))
        lines.append(f"{'  mean height error mm':36s}" + shown)
        if r.progress_error is not None:
            pe = r.progress_error
            cells = [np.nanmean(pe[m]) if np.isfinite(pe[m]).any() else np.nan for _, m in groups]
            shown = "".join(f"{c:{n}.3f}" for c, n in zip(cells, w, strict=True))
            lines.append(f"{'  progress MAE':36s}" + shown)
    return "\n".join(lines)


def lowest_foot(keypoints: np.ndarray) -> np.ndarray:
    feet = [KP[n] for n in KEYPOINTS if n.endswith(("heel", "toe", "ankle"))]
    return np.asarray(np.nanmin(keypoints[:, feet, 2], axis=1))


def measure(scene: Path, folder: Path, noise_mm: float) -> str:
    truth = export(simulate(scene, folder / "truth.scotti"), folder, noise_mm)
    rows: list[Row] = []
    for name, csv_name, floor in (
        ("camera", "camera.csv", None),
        ("hip-centred", "hip-centred.csv", None),
        ("hip-centred, floor = feet", "hip-centred.csv", "feet"),
    ):
        out = folder / f"{csv_name[:-4]}-{floor}.scotti"
        rc, err = run_import(import_args(folder, csv_name, floor), out)
        if rc != 0:
            rows.append(row(name, as_is(folder), truth, None, f"refused (exit {rc}): {err}"))
            continue
        ours, progress = imported(out, truth)
        rows.append(row(name, ours, truth, progress))
    return table(truth, rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python experiments/keypoints_floor.py")
    parser.add_argument("scenes", nargs="*", type=Path, default=list(SCENES))
    parser.add_argument("--noise-mm", type=float, default=0.0)
    parser.add_argument("--keep", type=Path, help="keep the files here (default: a temp folder)")
    args = parser.parse_args(argv)
    for scene in args.scenes:
        with tempfile.TemporaryDirectory() as tmp:
            folder = args.keep / scene.stem if args.keep else Path(tmp)
            folder.mkdir(parents=True, exist_ok=True)
            print(f"{scene.relative_to(ROOT) if scene.is_absolute() else scene}, "
                  f"noise {args.noise_mm:g} mm:")  # fmt: skip
            print(measure(scene, folder, args.noise_mm))
            print()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
