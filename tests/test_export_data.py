"""Session files -> training arrays -> windows, on real files written with the real writer."""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("torch")  # export/ is the [train] extra's room

from scotti.export.augment import add_crosstalk, draw_crosstalk, draw_shifts, shift_feet
from scotti.export.data import (
    TrainingDataError,
    decode_session,
    find_sessions,
    load_session,
)
from scotti.export.epochs import batch_tensors, plan_epoch
from scotti.export.train import TrainOptions
from scotti.export.windows import WindowDataset, split_by_subject
from scotti.firmware_protocol.pairing import HOLD_FRAMES
from scotti.firmware_protocol.pairing import RESTART_GAP_FRAMES as MAX_GAP
from scotti.models import contract
from scotti.models.insole import insole_mask
from scotti.sim.effects.sensor import Crosstalk, CrosstalkParams

from tests.support.export_sessions import COLS, ROWS, foot_counts, label_for, write_session

pytestmark = pytest.mark.torch

FRAMES = 200
FIRST_SEQ = 65536 - 60  # wraps after 60 frames
MISSING_RIGHT = 30  # the right foot's frame 30 never comes
MISSING_ROWS = 50  # the left foot's frame 50 lacks rows 0..7 (its first packet)
SILENT = range(120, 120 + HOLD_FRAMES + 4)  # the right foot is silent for 12 frames
# Held for 8, then zero-filled; the daemon sends a moment of a foot known silent without
# waiting for it, so the right's first frame back comes after its moment: late, zeros too.
ZEROED = range(120 + HOLD_FRAMES, SILENT.stop + 1)
LOST_RIGHT = [MISSING_RIGHT, *range(SILENT.start, ZEROED.stop)]
T = 8


@pytest.fixture(scope="module")
def lossy_session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_session(
        tmp_path_factory.mktemp("sessions") / "lossy.scotti",
        FRAMES,
        first_seq=FIRST_SEQ,
        drop_foot=[(MISSING_RIGHT, 1), *((k, 1) for k in SILENT)],
        drop_rows=[(MISSING_ROWS, 0, 0)],
        garbage_every=17,
    )


def test_decode_joins_feet_by_seq_across_the_wrap(lossy_session: Path) -> None:
    s = decode_session(lossy_session)
    k = np.arange(FRAMES)
    assert len(s) == FRAMES
    assert np.array_equal(s.seq - s.seq[0], k)  # one slot per frame, across 65535 -> 0
    assert np.array_equal(s.seq % 65536, (FIRST_SEQ + k) % 65536)
    assert s.frames.shape == (FRAMES, ROWS, 2 * COLS)
    assert s.frames.dtype == np.uint16
    # Taxel (0, 0) of each foot carries k + 1: left in column 0, right in column W.
    left = s.frames[:, 0, 0].astype(np.int64)
    assert np.array_equal(np.delete(left, MISSING_ROWS), np.delete(k + 1, MISSING_ROWS))
    right = s.frames[:, 0, COLS].astype(np.int64)
    assert np.array_equal(np.delete(right, LOST_RIGHT), np.delete(k + 1, LOST_RIGHT))
    assert s.subject == "s1"
    assert s.counters["decode_errors"] > 0  # the garbage was seen and counted


def test_missing_rows_and_feet_are_repaired_as_the_daemon_does(lossy_session: Path) -> None:
    s = decode_session(lossy_session)
    # Right frame 30 never came: the right foot's frame 29 is held in its place.
    assert s.valid[MISSING_RIGHT].tolist() == [True, False]
    assert s.repaired[MISSING_RIGHT].tolist() == [False, True]
    assert np.array_equal(s.frames[MISSING_RIGHT, :, COLS:], foot_counts(MISSING_RIGHT - 1, 1))
    # Left frame 50 lost rows 0..7: they come from left frame 49, the rest is its own.
    left, right = s.frames[MISSING_ROWS, :, :COLS], s.frames[MISSING_ROWS, :, COLS:]
    assert s.valid[MISSING_ROWS].tolist() == [False, True]
    assert s.repaired[MISSING_ROWS].tolist() == [True, False]
    assert np.array_equal(left[:8], foot_counts(MISSING_ROWS - 1, 0)[:8])
    assert np.array_equal(left[8:], foot_counts(MISSING_ROWS, 0)[8:])
    assert np.array_equal(right, foot_counts(MISSING_ROWS, 1))  # the other foot is whole
    # A long silence: held for HOLD_FRAMES, then zeros and not ok.
    held = s.frames[SILENT.start : ZEROED.start, :, COLS:]
    assert (held == foot_counts(SILENT.start - 1, 1)).all()
    assert not s.frames[ZEROED.start : ZEROED.stop, :, COLS:].any()
    assert np.flatnonzero(~s.frame_ok).tolist() == list(ZEROED)
    assert s.counters["missing_right"] == len(LOST_RIGHT)
    assert s.counters["incomplete_frames"] == 1
    assert s.counters["zero_filled"] == len(ZEROED)


def test_labels_land_on_their_seq(lossy_session: Path) -> None:
    s = decode_session(lossy_session)
    assert s.has_label.all()
    assert label_for(FRAMES - 1)[1] == contract.STANDING
    for k in (0, 59, 60, 61, MISSING_RIGHT, FRAMES - 1):
        kp, action, progress = label_for(k)
        assert np.array_equal(s.keypoints[k], kp)
        assert s.action[k] == action
        if not contract.has_progress(action):  # a transition, or standing (k = 199)
            assert np.isnan(s.progress[k])
        else:
            assert s.progress[k] == pytest.approx(progress)


def test_windows_predict_exactly_one_frame_ahead(lossy_session: Path) -> None:
    s = decode_session(lossy_session)
    ds = WindowDataset([s], window=T)
    whole = [i for i in ds.starts(0) if s.valid[i : i + T].all()]  # no repaired frame in it
    assert len(whole) > 100
    for i in whole:
        frames, target = ds.window_at(0, int(i))
        assert np.array_equal(frames[:, 0, 0], np.arange(i, i + T) + 1)  # frames i .. i+T-1
        kp, action, _ = label_for(int(i) + T)  # the label of frame i+T
        assert np.array_equal(target.keypoints[0], kp)
        assert target.action[0] == action


def test_windows_with_a_zero_filled_foot_are_dropped_unless_allowed(
    lossy_session: Path,
) -> None:
    s = decode_session(lossy_session)
    strict = set(WindowDataset([s], window=T).starts(0).tolist())
    loose = set(WindowDataset([s], window=T, allow_invalid=True).starts(0).tolist())
    touching = {i for i in range(FRAMES - T) if set(range(i, i + T)) & set(ZEROED)}
    assert strict == set(range(FRAMES - T)) - touching
    assert loose == set(range(FRAMES - T))
    assert ZEROED.start - T in strict  # a zero-filled frame may still be a window's target


def test_a_long_outage_splits_segments_and_no_window_spans_it(tmp_path: Path) -> None:
    path = write_session(tmp_path / "gap.scotti", 60, seq_jump=(30, MAX_GAP + 20))
    s = decode_session(path)
    assert len(s) == 60  # the gap is not filled with empty slots
    assert s.segment.tolist() == [0] * 30 + [1] * 30
    starts = WindowDataset([s], window=T).starts(0)
    assert set(starts.tolist()) == set(range(30 - T)) | set(range(30, 60 - T))


def test_chunks_cover_the_usable_windows_at_the_stride(lossy_session: Path) -> None:
    ds = WindowDataset([decode_session(lossy_session)], window=T)
    rng = np.random.default_rng(0)
    for stride, phase in ((1, 0), (3, 2)):
        chunks = ds.chunks(stride=stride, chunk=5, phase=phase, rng=rng)
        covered = [c.start + j * stride for c in chunks for j in range(c.count)]
        assert sorted(covered) == ds.starts(0, stride, phase).tolist()
        assert all(1 <= c.count <= 5 for c in chunks)
        c = chunks[len(chunks) // 2]
        assert ds.frames(c).shape[0] == (c.count - 1) * stride + T


def test_cache_is_reused_and_renewed_when_the_file_changes(tmp_path: Path) -> None:
    path = write_session(tmp_path / "a.scotti", 80)
    cache = tmp_path / "cache"
    first = load_session(path, cache)
    files = list(cache.glob("*.npz"))
    assert len(files) == 1
    again = load_session(path, cache)
    assert np.array_equal(again.frames, first.frames)
    assert again.counters == first.counters
    assert np.array_equal(again.progress, first.progress, equal_nan=True)
    write_session(path, 90)  # same name, new content
    os.utime(path, ns=(1, 1))
    assert len(load_session(path, cache)) == 90
    assert len(list(cache.glob("*.npz"))) == 2


def test_split_holds_out_whole_subjects(tmp_path: Path) -> None:
    sessions = [
        load_session(write_session(tmp_path / f"{who}.scotti", 60, subject=who))
        for who in ("a", "b", "c")
    ]
    split = split_by_subject(sessions, ["c"])
    assert [s.subject for s in split.test] == ["c"]
    assert split.kind == "subject"
    assert {s.subject for s in split.train} == {"a", "b"}
    seeded = split_by_subject(sessions, seed=1)
    assert len(seeded.test_subjects) == 1
    assert seeded.test_subjects[0] not in seeded.train_subjects
    with pytest.raises(TrainingDataError, match="unknown test subject"):
        split_by_subject(sessions, ["zed"])


def test_a_single_subject_is_split_in_time(tmp_path: Path) -> None:
    s = load_session(write_session(tmp_path / "one.scotti", 100, subject=None))
    assert s.subject == "one"  # no subject in the header: the file name
    split = split_by_subject([s], test_fraction=0.2)
    assert split.kind == "time"
    assert len(split.train[0]) == 80
    assert split.test[0].seq[0] == s.seq[80]


def test_find_sessions_by_magic_and_bad_paths(tmp_path: Path) -> None:
    write_session(tmp_path / "x.anything", 10)
    (tmp_path / "notes.txt").write_text("not a session")
    assert [p.name for p in find_sessions([tmp_path])] == ["x.anything"]
    with pytest.raises(TrainingDataError, match="no such file"):
        find_sessions([tmp_path / "missing"])
    with pytest.raises(TrainingDataError, match="no such session"):
        load_session(tmp_path / "missing.scotti")


def test_shift_moves_each_foot_on_its_own_and_fills_zeros() -> None:
    frames = np.zeros((2, ROWS, 2 * COLS), dtype=np.uint16)
    frames[:, 5, 0] = 7  # left foot, at its inner edge
    frames[:, 5, COLS] = 9  # right foot, at its inner edge
    out = shift_feet(frames, np.array([[1, -1], [-2, 2]]), COLS)
    assert out[:, :, :COLS].sum() == 0  # left pushed off its edge: lost, not wrapped
    assert out[0, 3, COLS + 2] == 9
    assert out[:, :, COLS:].sum() == 18
    same = shift_feet(frames, np.zeros((2, 2), dtype=np.int64), COLS)
    assert np.array_equal(same, frames)
    shifts = draw_shifts(np.random.default_rng(0), 2)
    assert shifts.shape == (2, 2)
    assert np.abs(shifts).max() <= 2


def test_added_crosstalk_is_the_simulators_effect_per_foot() -> None:
    rng = np.random.default_rng(4)
    mask = insole_mask()
    rows, cols = mask.shape
    feet = rng.uniform(0, 3000, size=(3, 2, rows, cols)).astype(np.float32) * mask
    frames = np.concatenate([feet[:, 0], feet[:, 1]], axis=2)  # (L, H, 2W) as the model sees
    fractions = np.array([0.02, 0.0], dtype=np.float32)
    out = add_crosstalk(frames, fractions, cols)
    # The simulator's stage on (n, 2, H, W), left foot only (the right gets 0 here).
    left = Crosstalk(CrosstalkParams(fraction=0.02), mask.astype(np.float32)).apply(feet[:, :1])
    np.testing.assert_allclose(out[:, :, :cols], np.minimum(left[:, 0], contract.MAX_COUNT))
    assert np.array_equal(out[:, :, cols:], frames[:, :, cols:])  # no crosstalk: unchanged
    assert (out[:, :, :cols][:, ~mask] == 0).all()  # no taxel outside the outline
    assert out.max() <= contract.MAX_COUNT  # the sum rails at full scale
    assert out[:, :, :cols].sum() > frames[:, :, :cols].sum()
    drawn = draw_crosstalk(np.random.default_rng(0), 0.03)
    assert drawn.shape == (2,)
    assert ((drawn >= 0) & (drawn <= 0.03)).all()
    assert not draw_crosstalk(np.random.default_rng(0), 0.0).any()


def test_an_epoch_plan_draws_crosstalk_only_when_asked(tmp_path: Path) -> None:
    ds = WindowDataset([load_session(write_session(tmp_path / "a.ses", 200))], window=8)
    plain = plan_epoch(ds, TrainOptions(batch=8, chunk=4, stride=2), epoch=1)
    assert not any(p.crosstalk.any() for b in plain for p in b)
    opts = TrainOptions(batch=8, chunk=4, stride=2, max_crosstalk=0.03)
    planned = [p for b in plan_epoch(ds, opts, epoch=1) for p in b]
    drawn = np.stack([p.crosstalk for p in planned])
    assert ((drawn >= 0) & (drawn <= 0.03)).all()
    assert len(np.unique(drawn)) > 1  # a fresh amount per chunk and foot
    again = [p for b in plan_epoch(ds, opts, epoch=1) for p in b]
    assert np.array_equal(drawn, np.stack([p.crosstalk for p in again]))  # resumable
    frames, _ = batch_tensors(ds, plan_epoch(ds, opts, epoch=1)[0])
    bare, _ = batch_tensors(ds, [replace(p, crosstalk=np.zeros(2)) for p in planned[:1]])
    assert frames[0].sum() > bare[0].sum()  # the batch carries it
