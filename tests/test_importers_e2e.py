"""import -> session -> info, render -> train (fine-tune) -> export -> eval, on recordings
of other shapes: another grid, another frame rate, a smaller keypoint set, a camera frame."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scotti.cli.main import main
from scotti.firmware_protocol.assembly import FrameAssembler
from scotti.firmware_protocol.framing import StreamDecoder
from scotti.firmware_protocol.packets import FrameRows
from scotti.firmware_protocol.session import read_session
from scotti.importers.keypoint_sets import MEDIAPIPE33
from scotti.models.contract import ACTIONS, NO_ACTION
from scotti.models.insole import insole_mask

from tests.support.foreign import (
    in_set,
    pressure_frames,
    squat_pose,
    to_camera,
    write_keypoints_csv,
    write_pressure_csv,
)

TINY_CHECKPOINT = Path(__file__).parent / "data" / "tiny" / "scotti-tiny.pt"


def session_counts(path: Path) -> np.ndarray:
    """(N, 2, 32, 22) counts of a session, decoded and assembled as the daemon does."""
    session = read_session(path)
    decoder, assembler = StreamDecoder(), FrameAssembler()
    frames: dict[tuple[int, int], np.ndarray] = {}
    for record in session.packets:
        for item in decoder.feed(record.data):
            assert isinstance(item, FrameRows)
            for frame in assembler.push(item, record.t_ns):
                frames[frame.seq, int(frame.foot)] = frame.counts
    for frame in assembler.flush():
        frames[frame.seq, int(frame.foot)] = frame.counts
    seqs = sorted({s for s, _ in frames})
    return np.stack([np.stack([frames[s, 0], frames[s, 1]]) for s in seqs])


def test_resampled_counts_equal_hand_computed_ones(tmp_path: Path) -> None:
    # An 8 x 11 grid at 10 Hz, one (N, 2, rows, cols) array, the left foot stored
    # toes-last; 2 units per kPa. Each source taxel covers 4 x 2 of ours, and a
    # constant recording resamples to itself, so our counts follow from the
    # transfer curve by hand: 4095 q^0.8 / (q^0.8 + 180^0.8), q = p - 20 kPa (0 below
    # the activation threshold), at most 3800 counts (models/insole.py).
    kpa_by_row = np.array([3.0, 78.0, 128.0, 78.0, 3.0, 128.0, 78.0, 128.0])
    ours_by_row = np.array([0, 1179, 1635, 1179, 0, 1635, 1179, 1635])  # 4095 * 0.2878 = 1179
    frame = np.repeat(kpa_by_row[:, None], 11, axis=1)
    both = np.stack([frame[::-1], frame])  # left toes-last, right as ours
    n = 30
    np.savez(
        tmp_path / "p.npz",
        t=np.arange(n) / 10.0,
        frames=np.repeat(2.0 * both[None], n, axis=0),
    )
    (tmp_path / "import.toml").write_text(
        '[pressure]\nfile = "p.npz"\nrows = 8\ncols = 11\ntime_key = "t"\n'
        'frames_key = "frames"\n[pressure.left]\ntoes = "last_row"\n'
        '[counts]\nmethod = "per_kpa"\nunits_per_kpa = 2.0\n'
    )
    out = tmp_path / "s.scotti"
    assert main(["import", str(tmp_path / "import.toml"), "-o", str(out)]) == 0
    counts = session_counts(out)
    assert counts.shape == (1 + int(2.9 * 16), 2, 32, 22)  # 0 .. 2.9 s at 16 Hz
    expected = np.repeat(ours_by_row, 4)[:, None] * insole_mask()
    for foot in range(2):
        np.testing.assert_array_equal(counts[:, foot], np.broadcast_to(expected, (47, 32, 22)))


def test_hdf5_pressure_imports_like_npz(tmp_path: Path) -> None:
    h5py = pytest.importorskip("h5py")
    t = np.arange(0, 3, 1 / 40)
    frames = pressure_frames(t, 12, 6)
    with h5py.File(tmp_path / "p.h5", "w") as f:
        f["insoles/time_s"] = t
        f["insoles/left"] = frames[:, 0]
        f["insoles/right"] = frames[:, 1]
    np.savez(tmp_path / "p.npz", time=t, left=frames[:, 0], right=frames[:, 1])
    common = ["--grid", "12x6", "--counts-per-kpa", "1"]
    (tmp_path / "h5.toml").write_text(
        '[pressure]\nfile = "p.h5"\nrows = 12\ncols = 6\ntime_key = "insoles/time_s"\n'
        'left_key = "insoles/left"\nright_key = "insoles/right"\n'
    )
    h5_args = [str(tmp_path / "h5.toml"), "--counts-per-kpa", "1"]
    assert main(["import", *h5_args, "-o", str(tmp_path / "a.scotti")]) == 0
    npz_args = ["--pressure", str(tmp_path / "p.npz"), *common]
    assert main(["import", *npz_args, "-o", str(tmp_path / "b.scotti")]) == 0
    a, b = session_counts(tmp_path / "a.scotti"), session_counts(tmp_path / "b.scotti")
    np.testing.assert_array_equal(a, b)
    assert a.max() > 1000  # the load is there


@pytest.fixture
def camera_recording(tmp_path: Path) -> Path:
    """A 16 x 8 insole at 50 Hz (left stored toes-last, right medial-last), MediaPipe
    keypoints at 30 Hz in a camera frame (y down, mm), squats from 1 s to 9 s."""
    t = np.arange(0, 10, 1 / 50)
    frames = pressure_frames(t, 16, 8)
    stored = frames.copy()
    stored[:, 0] = frames[:, 0, ::-1, :]
    stored[:, 1] = frames[:, 1, :, ::-1]
    write_pressure_csv(tmp_path / "insoles.csv", t * 1000, stored)
    tk = np.arange(0, 10, 1 / 30)
    camera = in_set(to_camera(squat_pose(tk)) * 1000, "mediapipe33")
    write_keypoints_csv(tmp_path / "pose.csv", tk, camera, MEDIAPIPE33)
    (tmp_path / "segments.csv").write_text("start,end,action\n1.0,9.0,squat\n")
    (tmp_path / "import.toml").write_text(
        'subject = "p01"\n[pressure]\nfile = "insoles.csv"\nrows = 16\ncols = 8\n'
        'time_unit = "ms"\n[pressure.left]\ntoes = "last_row"\n[pressure.right]\n'
        'medial = "last_col"\n[counts]\nmethod = "per_kpa"\nunits_per_kpa = 1.0\n'
        '[keypoints]\nfile = "pose.csv"\nset = "mediapipe33"\nup = "-y"\nunits = "mm"\n'
        '[labels]\nsegments = "segments.csv"\n'
    )
    return tmp_path


@pytest.mark.torch
@pytest.mark.slow
def test_import_train_export_eval(
    camera_recording: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    torch = pytest.importorskip("torch")
    d = camera_recording
    session = d / "p01.scotti"
    assert main(["import", str(d / "import.toml"), "-o", str(session)]) == 0
    assert "17 of 19 mapped" in capsys.readouterr().out

    assert main(["session", "info", str(session)]) == 0
    info = capsys.readouterr().out
    assert "imported" in info
    assert "insoles.csv (16 x 8, 500 frames at 50 Hz)" in info
    assert "bad packets none" in info
    labels = read_session(session).labels
    assert len(labels) == 160  # 0 .. 9.9375 s at 16 Hz
    squats = [lab for lab in labels if lab.action != NO_ACTION]
    assert len(squats) == 128  # 1.0 <= t < 9.0
    assert all(np.isfinite(lab.progress) for lab in squats)

    assert main(["sim", "render", str(session), "-o", str(d / "p01.png")]) == 0
    assert (d / "p01.png").stat().st_size > 10_000

    run = tmp_path / "runs" / "ft"
    train = [str(session), "-o", str(run), "--init", str(TINY_CHECKPOINT), "--freeze", "cnn"]
    train += ["--epochs", "1", "--batch", "16", "--chunk", "8", "--stride", "4", "--no-progress"]
    # One subject, no test set; validation is a time split: the last 4 s hold 24 windows.
    train += ["--test-fraction", "0", "--val-fraction", "0.4"]
    assert main(["train", *train]) == 0
    tuned = torch.load(run / "last.pt", weights_only=True)
    start = torch.load(TINY_CHECKPOINT, weights_only=True)
    assert tuned["training_data"]["init"] == str(TINY_CHECKPOINT)
    for name, value in tuned["model"].items():
        same = torch.equal(value, start["model"][name])
        if name.startswith("cnn."):
            assert same, name  # frozen, batch-norm statistics included
    assert not torch.equal(
        tuned["model"]["pose_head.3.weight"], start["model"]["pose_head.3.weight"]
    )
    val = tuned["metrics"]["val"]
    assert np.isfinite(val["mpjpe_mm"])  # over the 17 keypoints the labels have

    model = tmp_path / "ft.onnx"
    assert main(["export", str(run / "last.pt"), "-o", str(model)]) == 0
    capsys.readouterr()
    assert main(["eval", str(session), "--model", str(model), "--json", "--every", "4"]) == 0
    report = json.loads(capsys.readouterr().out)
    scored = report["sessions"][0]
    assert scored["evaluated"] > 20
    assert np.isfinite(scored["metrics"]["mpjpe_mm"])
    assert np.isfinite(scored["metrics"]["progress_mse"])


def test_a_pressure_only_import_has_info_and_a_picture(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    t = 50.0 + np.arange(0, 3, 1 / 25)  # 25 Hz on a clock that starts at 50 s
    t = np.r_[t, t[-1] + 2.0 + np.arange(0, 1, 1 / 25)]  # a 2 s gap: two segments
    np.savez(tmp_path / "p.npz", time=t, left=pressure_frames(t, 10, 5)[:, 0],
             right=pressure_frames(t, 10, 5)[:, 1])  # fmt: skip
    out = tmp_path / "p.scotti"
    args = ["--pressure", str(tmp_path / "p.npz"), "--grid", "10x5", "--counts-per-kpa", "1"]
    assert main(["import", *args, "-o", str(out)]) == 0
    assert "in 2 segment(s)" in capsys.readouterr().out
    assert main(["session", "info", str(out)]) == 0
    info = capsys.readouterr().out
    assert "labels    none" in info
    assert "2 segments" in info
    assert "sequence gaps                1         1" in info
    packets = read_session(out).packets
    assert packets[0].t_ns == 50_000_000_000  # the source's own clock, in ns
    assert main(["sim", "render", str(out), "-o", str(tmp_path / "p.png")]) == 0
    assert (tmp_path / "p.png").stat().st_size > 10_000


def test_one_stream_per_insole_with_its_own_clock(tmp_path: Path) -> None:
    # ActionNet-style: /insole-left and /insole-right, each with data and time_s,
    # at 40 Hz and 37 Hz. Pressure that grows linearly in time interpolates exactly,
    # so the import equals one made from both feet on the left foot's times.
    h5py = pytest.importorskip("h5py")
    base = pressure_frames(np.zeros(1), 12, 6)[0]  # (2, 12, 6) kPa

    def at(t: np.ndarray, foot: int) -> np.ndarray:
        return base[foot][None] * (1.0 + 0.2 * t[:, None, None])

    t_left = 10.0 + np.arange(0, 3, 1 / 40)
    t_right = 9.9 + np.arange(0, 3.3, 1 / 37)  # covers the left's span
    with h5py.File(tmp_path / "p.h5", "w") as f:
        for name, t, foot in (("left", t_left, 0), ("right", t_right, 1)):
            f[f"insole-{name}/tactile_data/data"] = at(t, foot)
            f[f"insole-{name}/tactile_data/time_s"] = t
    (tmp_path / "a.toml").write_text(
        '[pressure]\nfile = "p.h5"\nrows = 12\ncols = 6\n'
        'time_key = "insole-left/tactile_data/time_s"\n'
        'right_time_key = "insole-right/tactile_data/time_s"\n'
        'left_key = "insole-left/tactile_data/data"\n'
        'right_key = "insole-right/tactile_data/data"\n'
        '[counts]\nmethod = "per_kpa"\nunits_per_kpa = 1.0\n'
    )
    np.savez(tmp_path / "b.npz", time=t_left, left=at(t_left, 0), right=at(t_left, 1))
    assert main(["import", str(tmp_path / "a.toml"), "-o", str(tmp_path / "a.scotti")]) == 0
    args = ["--pressure", str(tmp_path / "b.npz"), "--grid", "12x6", "--counts-per-kpa", "1"]
    assert main(["import", *args, "-o", str(tmp_path / "b.scotti")]) == 0
    a, b = session_counts(tmp_path / "a.scotti"), session_counts(tmp_path / "b.scotti")
    assert np.abs(a.astype(int) - b.astype(int)).max() <= 1  # float32 rounding at most


def test_flags_alone_import_pressure_keypoints_and_one_action(
    camera_recording: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    d = camera_recording
    args = ["--pressure", str(d / "insoles.csv"), "--grid", "16x8", "--time-unit", "ms"]
    args += ["--counts-per-kpa", "1", "--keypoints", str(d / "pose.csv")]
    args += ["--keypoint-set", "mediapipe33", "--up=-y", "--units", "mm", "--action", "squat"]
    out = d / "flags.scotti"
    assert main(["import", *args, "--subject", "p02", "-o", str(out)]) == 0
    session = read_session(out)
    assert session.header.subject == {"id": "p02"}
    labels = session.labels
    assert len(labels) == 160
    assert {lab.action for lab in labels} == {ACTIONS.index("squat")}
    assert np.isfinite(labels[80].keypoints).all(axis=1).sum() == 17
