"""export/tempo.py: a chunk of training windows played slower or faster.

A session whose every value is its own slot number shows where each frame and
target is read; a jump, a segment break, a zero-filled foot or a missing label
inside the span keeps the chunk at its own tempo; off, the epoch's plan is the
plan of a run without the augmentation.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scotti.export import tempo
from scotti.export.data import SessionArrays
from scotti.export.windows import Chunk, WindowDataset
from scotti.models.contract import ACTIONS

WALKING, JUMP = ACTIONS.index("walking"), ACTIONS.index("jump")


def ramp_session(n: int = 200) -> SessionArrays:
    """Every frame's taxels, every keypoint coordinate and the progress read their slot."""
    slots = np.arange(n)
    return SessionArrays(
        path="ramp",
        subject="r",
        frames=np.broadcast_to(slots[:, None, None], (n, 4, 6)).astype(np.uint16),
        valid=np.ones((n, 2), dtype=bool),
        repaired=np.zeros((n, 2), dtype=bool),
        seq=slots.astype(np.int64),
        segment=np.zeros(n, dtype=np.int32),
        has_label=np.ones(n, dtype=bool),
        keypoints=np.broadcast_to(slots[:, None, None], (n, 19, 3)).astype(np.float32),
        action=np.full(n, WALKING, dtype=np.int64),
        progress=(slots / n).astype(np.float32),
    )


CHUNK = Chunk(session=0, start=20, count=3, stride=4, window=8)  # 16 frames, targets 28, 32, 36


def test_a_slower_chunk_reads_between_slots_and_its_targets_move_with_it() -> None:
    ds = WindowDataset([ramp_session()], window=8)
    frames = ds.frames(CHUNK, 0.5)
    assert frames.dtype == np.float32
    assert frames.shape == (16, 4, 6)
    np.testing.assert_allclose(frames[:, 0, 0], 20 + 0.5 * np.arange(16))
    targets = ds.targets(CHUNK, 0.5)
    np.testing.assert_allclose(targets.keypoints[:, 0, 0], [24.0, 26.0, 28.0])
    assert targets.action.tolist() == [WALKING] * 3
    np.testing.assert_allclose(targets.progress, np.array([24, 26, 28]) / 200)


def test_a_faster_chunk_reads_further_and_its_progress_is_the_nearest_slot() -> None:
    ds = WindowDataset([ramp_session()], window=8)
    frames = ds.frames(CHUNK, 1.25)
    np.testing.assert_allclose(frames[-1, 0, 0], 20 + 1.25 * 15)
    targets = ds.targets(CHUNK, 1.25)
    np.testing.assert_allclose(targets.keypoints[:, 0, 0], [30.0, 35.0, 40.0])
    s = ramp_session()
    s.progress[31] = 0.9  # a rep ends between slots 30 and 31: no value in between
    ds = WindowDataset([s], window=8)
    chunk = replace(CHUNK, start=20, count=1, stride=1, window=9)  # target at 20 + 1.2 * 9
    assert ds.targets(chunk, 1.2).progress.tolist() == pytest.approx([s.progress[31]])


def test_tempo_one_is_the_chunk_as_recorded() -> None:
    ds = WindowDataset([ramp_session()], window=8)
    assert ds.frames(CHUNK, 1.0).dtype == np.uint16
    np.testing.assert_array_equal(ds.frames(CHUNK, 1.0), ds.frames(CHUNK))
    np.testing.assert_array_equal(ds.targets(CHUNK, 1.0).keypoints, ds.targets(CHUNK).keypoints)


@pytest.mark.parametrize(
    ("spoil", "tempo_value"),
    [
        (lambda s: s.action.__setitem__(40, JUMP), 1.25),  # a jump inside the faster span
        (lambda s: s.segment.__setitem__(slice(30, None), 1), 0.8),  # a restart inside
        (lambda s: s.valid.__setitem__((25, 0), False), 0.8),  # a zero-filled foot
        (lambda s: s.has_label.__setitem__(27, False), 0.8),  # a target next to no label
    ],
)
def test_a_span_a_window_may_not_use_keeps_the_chunk_as_recorded(
    spoil: Callable[[SessionArrays], None], tempo_value: float
) -> None:
    s = ramp_session()
    ds = WindowDataset([s], window=8)
    assert ds.fits_tempo(CHUNK, tempo_value)
    spoil(s)
    assert not ds.fits_tempo(CHUNK, tempo_value)
    assert ds.fits_tempo(CHUNK, 1.0)  # its own tempo is always allowed


def test_a_faster_chunk_past_the_session_end_does_not_fit() -> None:
    ds = WindowDataset([ramp_session(50)], window=8)
    chunk = Chunk(0, 30, 3, 4, 8)  # frames to slot 45, targets to 46 of 0..49
    assert ds.fits_tempo(chunk, 1.0)
    assert ds.fits_tempo(chunk, 1.1)  # the last target at 30 + 1.1 * 16 = 47.6
    assert not ds.fits_tempo(chunk, 1.3)  # at 50.8: past the last slot


def test_draws_stay_in_the_range_and_off_draws_nothing() -> None:
    rng = np.random.default_rng(0)
    draws = [tempo.draw_tempo(rng, 1.0, 0.65, 1.3) for _ in range(500)]
    assert min(draws) >= 0.65
    assert max(draws) <= 1.3
    assert sum(d < 1.0 for d in draws) > 150  # log-uniform: about 62 % below 1
    assert sum(d > 1.0 for d in draws) > 100
    a, b = np.random.default_rng(1), np.random.default_rng(1)
    assert tempo.draw_tempo(a, 0.0, 0.65, 1.3) == 1.0
    assert a.random() == b.random()  # nothing was drawn


def test_an_extra_share_draws_its_own_range_beside_the_first() -> None:
    rng = np.random.default_rng(3)
    n = 4000
    draws = np.array([tempo.draw_tempo(rng, 0.3, 0.9, 1.1, 0.2, (2.0, 3.0)) for _ in range(n)])
    near = (draws >= 0.9) & (draws <= 1.1) & (draws != 1.0)
    extra = (draws >= 2.0) & (draws <= 3.0)
    assert near.mean() == pytest.approx(0.3, abs=0.03)
    assert extra.mean() == pytest.approx(0.2, abs=0.03)
    assert (draws == 1.0).mean() == pytest.approx(0.5, abs=0.03)
    assert near.sum() + extra.sum() + (draws == 1.0).sum() == n  # nothing anywhere else
    # The extra share alone stretches every chunk it is given, within its own range.
    alone = [tempo.draw_tempo(rng, 0.0, 0.65, 1.3, 1.0, (0.3, 3.0)) for _ in range(500)]
    assert min(alone) >= 0.3
    assert max(alone) <= 3.0
    assert sum(d < 0.65 for d in alone) > 100
    assert sum(d > 1.3 for d in alone) > 100


def test_without_an_extra_share_the_draws_are_those_of_before_it_existed() -> None:
    def before(rng: np.random.Generator, share: float, low: float, high: float) -> float:
        # draw_tempo as it was before --tempo-extra (runs up to v41 were planned by it)
        if share <= 0.0 or rng.random() >= share:
            return 1.0
        return float(math.exp(rng.uniform(math.log(low), math.log(high))))

    a, b = np.random.default_rng(5), np.random.default_rng(5)
    now = [tempo.draw_tempo(a, 0.3, 0.65, 1.3) for _ in range(300)]
    then = [before(b, 0.3, 0.65, 1.3) for _ in range(300)]
    assert now == then
    assert a.random() == b.random()  # the generator is left where it was left before


@pytest.mark.torch
def test_the_plan_plays_chunks_at_their_tempo_and_is_unchanged_when_off() -> None:
    pytest.importorskip("torch")
    from scotti.export.epochs import batch_tensors, plan_epoch
    from scotti.export.train import TrainOptions

    ds = WindowDataset([ramp_session(400)], window=8)
    off = TrainOptions(batch=8, chunk=4, stride=2, max_shift=0)
    plain = plan_epoch(ds, off, 0)
    assert all(p.tempo == 1.0 for b in plain for p in b)
    on = plan_epoch(ds, replace(off, tempo_stretch=1.0), 0)
    tempi = [p.tempo for b in on for p in b]
    assert sum(t != 1.0 for t in tempi) > len(tempi) // 2  # most fit; the last ones may not
    assert plan_epoch(ds, replace(off, tempo_stretch=1.0), 0)[0][0].tempo == on[0][0].tempo
    frames, targets = batch_tensors(ds, on[0])
    for got, p in zip(frames, on[0], strict=True):
        assert got.shape == (p.chunk.frame_count, 4, 6)
        start = p.chunk.start
        expected = start + p.tempo * np.arange(p.chunk.frame_count)
        np.testing.assert_allclose(got.numpy()[:, 1, 1], expected, rtol=1e-5)
    assert int(targets.action.shape[0]) == sum(p.chunk.count for p in on[0])


@pytest.mark.torch
@pytest.mark.slow
def test_scotti_train_takes_the_flags_records_them_and_refuses_bad_ones(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    torch = pytest.importorskip("torch")
    from scotti.cli.main import main

    from tests.support.export_sessions import TINY_MODEL, write_session

    torch.set_num_threads(1)
    write_session(tmp_path / "a.scotti", 110, subject="a")
    write_session(tmp_path / "b.scotti", 60, subject="b")
    run = tmp_path / "run"
    args = [str(tmp_path / "a.scotti"), str(tmp_path / "b.scotti"), "-o", str(run)]
    args += ["--config", json.dumps(TINY_MODEL), "--epochs", "1", "--batch", "8", "--chunk", "4"]
    args += ["--stride", "2", "--val-subjects", "b", "--test-fraction", "0", "--no-progress"]
    args += ["--device", "cpu"]
    tempo_flags = ["--tempo-stretch", "0.5", "--tempo-range", "0.7,1.2"]
    tempo_flags += ["--tempo-extra", "0.25", "--tempo-extra-range", "0.4,2.5"]
    assert main(["train", *args, *tempo_flags]) == 0
    ckpt = torch.load(run / "last.pt", weights_only=True)
    assert ckpt["options"]["tempo_stretch"] == 0.5
    assert tuple(ckpt["options"]["tempo_range"]) == (0.7, 1.2)
    assert ckpt["options"]["tempo_extra"] == 0.25
    assert tuple(ckpt["options"]["tempo_extra_range"]) == (0.4, 2.5)
    assert np.isfinite(ckpt["history"][-1]["train_loss"])
    bad = [
        ("--tempo-stretch=1.5", "--tempo-stretch must be a share between 0 and 1"),
        ("--tempo-range=1.1,1.3", "--tempo-range must have 0 < LO <= 1 <= HI <= 3"),
        ("--tempo-range=0.8", "--tempo-range must be two numbers LO,HI"),
        ("--tempo-range=a,b", "--tempo-range must be two numbers LO,HI"),
        ("--tempo-extra=1.5", "--tempo-extra must be a share between 0 and 1 - --tempo-stretch"),
        ("--tempo-extra-range=1.1,2", "--tempo-extra-range must have 0 < LO <= 1 <= HI <= 3"),
    ]
    for flag, message in bad:
        assert main(["train", *args, "-o", str(tmp_path / "r"), flag]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith(f"scotti train: {message}")
        assert "\n" not in err
