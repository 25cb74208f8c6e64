"""The unfamiliar score's windows drawn as the checkpoint's training drew them.

A model trained through foreign insoles and at other tempi calls windows
like those familiar; its calibration draws both sides the same way, from
the checkpoint's own options, repeatably, and says so on the card.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scotti.export.calibration_draws import InputDraws, drawn_window
from scotti.export.card import ood_markdown
from scotti.export.data import load_session
from scotti.export.make_tiny import build_tiny
from scotti.export.onnx_export import Checkpoint, export_model
from scotti.export.ood_calibration import Calibration, calibrate, gather, window_batches
from scotti.export.train_options import TrainOptions
from scotti.export.windows import WindowDataset
from scotti.models.contract import WINDOW

from tests.support.export_sessions import write_session

pytestmark = pytest.mark.torch

SPLIT = {"split": {"kind": "subject", "train_subjects": ["a", "b"], "test_subjects": ["c"]}}
TRAINED = InputDraws(sensor_transfer=1.0, tempo_stretch=1.0, tempo_range=(0.7, 0.8), seed=5)


def test_the_draws_are_read_from_a_checkpoints_training_options() -> None:
    opts = TrainOptions(sensor_transfer=0.5, tempo_stretch=0.3, tempo_range=(0.6, 1.2), seed=2)
    draws = InputDraws.from_options(opts.to_dict())
    assert draws == InputDraws(0.5, 0.3, (0.6, 1.2), 2)
    assert draws.active
    assert draws.describe()["sensor_transfer"] == 0.5
    # A checkpoint trained without them, or one that names no options, draws none.
    assert not InputDraws.from_options(TrainOptions().to_dict()).active
    assert InputDraws.from_options(None) == InputDraws()
    assert InputDraws().describe() == {"as_recorded": True}


def test_an_extra_tempo_share_is_read_drawn_and_described() -> None:
    opts = TrainOptions(tempo_extra=0.2, tempo_extra_range=(0.4, 2.5), seed=3)
    draws = InputDraws.from_options(opts.to_dict())
    assert draws.tempo_extra == 0.2
    assert draws.tempo_extra_range == (0.4, 2.5)
    assert draws.active  # the extra share alone is a draw
    described = draws.describe()
    assert described["tempo_extra"] == 0.2
    assert described["tempo_extra_range"] == [0.4, 2.5]
    # Without it the description is what it was (cards written before it stay comparable).
    assert "tempo_extra" not in TRAINED.describe()
    # The card names both shares.
    from scotti.export.card import _drawn

    assert _drawn(described).endswith("0 % at tempi 0.65-1.3 and 20 % at 0.4-2.5)")


def test_windows_as_recorded_are_the_sessions_frames(tmp_path: Path) -> None:
    write_session(tmp_path / "a.ses", 200, subject="a")
    sessions = [load_session(tmp_path / "a.ses")]
    plain = list(window_batches(sessions, 40))
    again = list(window_batches(sessions, 40, InputDraws(), side=0))
    for (w1, a1), (w2, a2) in zip(plain, again, strict=True):
        np.testing.assert_array_equal(w1, w2)
        np.testing.assert_array_equal(a1, a2)
    windows, _ = plain[0]
    data = WindowDataset(sessions, WINDOW)
    first = int(data.starts(0)[0])
    np.testing.assert_array_equal(windows[0], sessions[0].frames[first : first + WINDOW])


def test_drawn_windows_differ_from_the_recorded_and_repeat_per_side(tmp_path: Path) -> None:
    write_session(tmp_path / "a.ses", 300, subject="a")
    sessions = [load_session(tmp_path / "a.ses")]
    plain = np.concatenate([w for w, _ in window_batches(sessions, 40)])
    drawn = np.concatenate([w for w, _ in window_batches(sessions, 40, TRAINED, side=0)])
    again = np.concatenate([w for w, _ in window_batches(sessions, 40, TRAINED, side=0)])
    other = np.concatenate([w for w, _ in window_batches(sessions, 40, TRAINED, side=1)])
    assert drawn.shape == plain.shape
    np.testing.assert_array_equal(drawn, again)  # an export is repeatable
    assert not np.array_equal(drawn, other)  # the held-out side draws its own
    changed = [not np.array_equal(d, p) for d, p in zip(drawn, plain, strict=True)]
    assert all(changed)  # every window went through a foreign insole


def test_a_slower_tempo_reads_between_slots_and_keeps_the_label(tmp_path: Path) -> None:
    write_session(tmp_path / "a.ses", 300, subject="a")
    sessions = [load_session(tmp_path / "a.ses")]
    data = WindowDataset(sessions, WINDOW)
    start = int(data.starts(0)[0])
    slow = InputDraws(tempo_stretch=1.0, tempo_range=(0.5, 0.5))
    frames, action = drawn_window(data, 0, start, slow, np.random.default_rng(0))
    recorded = sessions[0].frames[start : start + WINDOW].astype(np.float32)
    # Frame 2 at tempo 0.5 is slot start + 1; frame 1 halfway between slots 0 and 1.
    np.testing.assert_allclose(frames[2], recorded[1])
    np.testing.assert_allclose(frames[1], (recorded[0] + recorded[1]) / 2)
    assert action == int(sessions[0].action[start + WINDOW // 2])


@pytest.mark.slow
def test_calibration_asked_to_draw_as_trained_moves_the_statistics_and_the_card_says_so(
    tmp_path: Path,
) -> None:
    for subject in ("a", "b", "c"):
        write_session(tmp_path / f"{subject}.ses", 200, subject=subject)
    ckpt = Checkpoint(
        model=build_tiny().eval(),
        training_data=SPLIT,
        options=TrainOptions(sensor_transfer=1.0, tempo_stretch=0.5, seed=5).to_dict(),
    )
    out = tmp_path / "models" / "m.onnx"
    request = Calibration(
        (tmp_path,), percentile=95.0, max_windows=60, progress_windows=0, as_trained=True
    )
    result = export_model(ckpt, out, calibration=request)
    drawn = result.card["ood"]["windows_drawn"]
    assert drawn == {
        "as_recorded": False,
        "sensor_transfer": 1.0,
        "tempo_stretch": 0.5,
        "tempo_range": [0.65, 1.3],
        "seed": 5,
    }
    card_md = out.with_suffix(".card.md").read_text()
    assert "drawn as training drew them (100 % through foreign insoles, 50 % at tempi" in card_md
    # The same graph calibrated on the windows as recorded fits other statistics.
    window = out.with_name("m.window.onnx")
    recorded = Calibration((tmp_path,), percentile=95.0, max_windows=60, draws=InputDraws())
    as_trained = Calibration(
        (tmp_path,), percentile=95.0, max_windows=60, draws=InputDraws.from_options(ckpt.options)
    )
    plain = calibrate(window, gather(SPLIT, recorded), recorded)
    trained = calibrate(window, gather(SPLIT, as_trained), as_trained)
    assert trained.threshold == pytest.approx(result.card["ood"]["threshold"])
    assert plain.summary["windows_drawn"] == {"as_recorded": True}
    assert not np.allclose(plain.mean, trained.mean)
    plain_md = "\n".join(ood_markdown({**plain.summary, "calibrated": True}))
    assert "drawn as training" not in plain_md


def test_export_calibrates_on_windows_as_recorded_unless_asked(tmp_path: Path) -> None:
    for subject in ("a", "b", "c"):
        write_session(tmp_path / f"{subject}.ses", 120, subject=subject)
    ckpt = Checkpoint(
        model=build_tiny().eval(),
        training_data=SPLIT,
        options=TrainOptions(sensor_transfer=1.0, seed=5).to_dict(),
    )
    request = Calibration((tmp_path,), percentile=95.0, max_windows=30, progress_windows=0)
    result = export_model(ckpt, tmp_path / "m" / "m.onnx", calibration=request)
    assert result.card["ood"]["windows_drawn"] == {"as_recorded": True}


@pytest.mark.slow
def test_the_cli_draws_as_trained_only_when_asked(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import torch
    from scotti.cli.main import main as scotti_main
    from scotti.export.make_tiny import tiny_checkpoint

    sessions = tmp_path / "sessions"
    sessions.mkdir()
    for subject in ("a", "b", "c"):
        write_session(sessions / f"{subject}.ses", 120, subject=subject)
    options = TrainOptions(sensor_transfer=1.0, tempo_stretch=0.5, seed=5).to_dict()
    ckpt = {**tiny_checkpoint(build_tiny()), "training_data": SPLIT, "options": options}
    torch.save(ckpt, tmp_path / "c.pt")
    common = ["--calibrate", str(sessions), "--ood-windows", "30", "--progress-windows", "0"]
    drawn = {}
    for name, extra in (("plain", []), ("trained", ["--calibrate-as-trained"])):
        out = tmp_path / name / "m.onnx"
        assert scotti_main(["export", str(tmp_path / "c.pt"), "-o", str(out), *common, *extra]) == 0
        card = out.with_suffix(".card.json").read_text()
        drawn[name] = '"as_recorded": true' in card
    assert drawn == {"plain": True, "trained": False}
    assert "windows drawn as trained: 1 through foreign insoles, 0.5" in capsys.readouterr().out
    # Asked of a checkpoint trained without them: as recorded, and it says why.
    torch.save({**ckpt, "options": TrainOptions().to_dict()}, tmp_path / "plain.pt")
    out = tmp_path / "plain" / "p.onnx"
    args = ["export", str(tmp_path / "plain.pt"), "-o", str(out), *common, "--calibrate-as-trained"]
    assert scotti_main(args) == 0
    assert '"as_recorded": true' in out.with_suffix(".card.json").read_text()
    assert "names no foreign insoles or tempi" in capsys.readouterr().out
