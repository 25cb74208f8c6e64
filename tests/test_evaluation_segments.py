"""Batched streaming (``evaluation.segments``): K segments of a session in each
step-graph call make exactly the predictions of the daemon's own window stepped frame
by frame."""

from __future__ import annotations

import json
import math
import threading
from pathlib import Path

import numpy as np
import numpy.typing as npt
import onnx
import pytest
from scotti.cli.main import main
from scotti.daemon.inference.window import Window
from scotti.evaluation import segments
from scotti.evaluation.evaluation import (
    SessionReplay,
    evaluate_models,
    evaluate_sessions,
    replay_session,
)
from scotti.evaluation.frames import Prediction
from scotti.firmware_protocol.frame_path import PairSeq, stream_pairs
from scotti.firmware_protocol.packets import Foot
from scotti.firmware_protocol.session import PacketRecord, SessionReader
from scotti.models.contract import MAX_COUNT, META_OOD
from scotti.models.input_checks import OUT_OF_RANGE, UNLOADED
from scotti.models.ood import UNFAMILIAR, OodStats, flag_shares
from scotti.models.runtime import ScottiRuntime, StepBatch

from tests.support.export_sessions import write_session
from tests.support.sessions import synthetic_counts, write_synthetic_session

FLAG_FRAMES = 230


@pytest.fixture
def small_segments(monkeypatch: pytest.MonkeyPatch) -> None:
    """Segments of a few frames and chunks of 100: a short session is cut many times,
    shorter than a window (40) too, and crosses chunk boundaries."""
    monkeypatch.setattr(segments, "MIN_SEGMENT_FRAMES", 1)
    monkeypatch.setattr(segments, "CHUNK_FRAMES", 100)


@pytest.fixture(scope="module")
def calibrated(tiny_model_path: Path, tmp_path_factory: pytest.TempPathFactory) -> ScottiRuntime:
    """The tiny step graph with OOD statistics whose threshold cuts its pooled vectors'
    norms on the flags session in half (mean 0, whitening I): some predictions unfamiliar."""
    plain = ScottiRuntime(tiny_model_path)
    t, e = plain.window, plain.embed_dim
    frames = np.stack([_counts_pair(i) for i in range(FLAG_FRAMES)]).astype(np.float32)
    # A frame's embedding does not depend on the past: one call gives them all.
    emb = plain.run_steps(frames, np.zeros((len(frames), t - 1, e), np.float32)).embedding
    past = np.stack([emb[j - t + 1 : j] for j in range(t - 1, len(frames))])
    pooled = plain.run_steps(frames[t - 1 :], past).pooled
    assert pooled is not None
    norms = np.linalg.norm(pooled, axis=1)
    stats = OodStats(np.zeros(e, np.float32), np.eye(e, dtype=np.float32), float(np.median(norms)))
    model = onnx.load(str(tiny_model_path))
    model.metadata_props.add(key=META_OOD, value=stats.to_json())
    out = tmp_path_factory.mktemp("calibrated") / "scotti-cal.onnx"
    onnx.save(model, str(out))
    return ScottiRuntime(out)


def _counts(foot: Foot, seq: int, i: int) -> np.ndarray:
    """A plausible map, then nobody on the insoles (unloaded), then saturated (out_of_range)."""
    if 80 <= i < 130:
        return np.zeros((32, 22), np.uint16)
    if 170 <= i < 190:
        return np.full((32, 22), MAX_COUNT, np.uint16)
    return synthetic_counts(foot, seq)


def _counts_pair(i: int) -> np.ndarray:
    return np.concatenate([_counts(Foot.LEFT, i, i), _counts(Foot.RIGHT, i, i)], axis=1)


def frame_by_frame(path: Path, runtime: ScottiRuntime) -> tuple[list[Prediction], int]:
    """The daemon's own ``Window`` stepped pair by pair: its predictions and restarts."""
    with SessionReader(path) as reader:
        chunks = [(r.t_ns, r.data) for r in reader if isinstance(r, PacketRecord)]
    window, seq, made = Window(runtime), PairSeq(), []
    for pair in stream_pairs(chunks):
        ext = seq.of(pair)
        if pair.restart:
            window.restart()
        result = window.push(pair.counts).result
        if result is not None and ext is not None:
            made.append(
                Prediction(ext + 1, result.pose, result.action_probs, result.progress, result.flags)
            )
    return made, window.restarts


def assert_same_replay(batched: SessionReplay, path: Path, runtime: ScottiRuntime) -> None:
    made, restarts = frame_by_frame(path, runtime)
    assert batched.window_restarts == restarts
    assert [m.ext for m in batched.made] == [m.ext for m in made]
    assert [m.flags for m in batched.made] == [m.flags for m in made]
    for ours, theirs in zip(batched.made, made, strict=True):
        np.testing.assert_allclose(ours.pose, theirs.pose, atol=1e-5)
        np.testing.assert_allclose(ours.probs, theirs.probs, atol=1e-5)
        assert ours.progress == pytest.approx(theirs.progress, abs=1e-5)
    assert flag_shares([m.flags for m in batched.made]) == flag_shares([m.flags for m in made])
    one = replay_session(path, runtime, batch=1)  # one segment: the same counts
    assert batched.summary() == one.summary()


@pytest.mark.parametrize("batch", [3, 7, 64])
@pytest.mark.usefixtures("small_segments")
def test_segments_predict_what_frame_by_frame_predicts(
    tmp_path: Path, tiny_model_path: Path, batch: int
) -> None:
    # 301 frames (no multiple of 3, 7 or 64), seqs wrapping, and both feet silent for
    # 20 frames (> 1 s): the window restarts mid-session, inside some segment.
    silent = {(k, foot) for k in range(150, 170) for foot in (0, 1)}
    path = write_session(tmp_path / "gap.ses", 301, first_seq=65_500, drop_foot=silent)
    runtime = ScottiRuntime(tiny_model_path)
    batched = replay_session(path, runtime, batch=batch)
    assert batched.window_restarts == 1
    assert len(batched.made) > 200
    assert_same_replay(batched, path, runtime)
    assert max(n for _, n in batched.step_batches) == batch  # it did run K segments at once


@pytest.mark.parametrize("frames", [25, 39, 40, 41, 55])
@pytest.mark.usefixtures("small_segments")
def test_sessions_around_one_window_long(
    tmp_path: Path, tiny_model_path: Path, frames: int
) -> None:
    path = write_session(tmp_path / "short.ses", frames)
    runtime = ScottiRuntime(tiny_model_path)
    batched = replay_session(path, runtime, batch=8)
    assert len(batched.made) == max(0, frames - runtime.window + 1)
    assert_same_replay(batched, path, runtime)


@pytest.mark.usefixtures("small_segments")
def test_flags_count_exactly_as_frame_by_frame(tmp_path: Path, calibrated: ScottiRuntime) -> None:
    path = write_synthetic_session(
        tmp_path / "flags.ses", frames=FLAG_FRAMES, counts_of=_counts
    ).path
    batched = replay_session(path, calibrated, batch=6)
    assert_same_replay(batched, path, calibrated)
    flags = [m.flags for m in batched.made]
    for flag in (UNLOADED, OUT_OF_RANGE, UNFAMILIAR):  # each one both set and not
        assert 0 < sum(flag in f for f in flags) < len(flags), flag


def test_a_long_session_keeps_its_default_segments_long(
    tmp_path: Path, tiny_model_path: Path
) -> None:
    # Default sizes: 900 frames make 2 segments of at least MIN_SEGMENT_FRAMES (400).
    path = write_session(tmp_path / "long.ses", 900)
    runtime = ScottiRuntime(tiny_model_path)
    batched = replay_session(path, runtime)
    assert max(n for _, n in batched.step_batches) == 2
    assert_same_replay(batched, path, runtime)


@pytest.mark.usefixtures("small_segments")
def test_cli_batch_reports_the_same_scores(
    tmp_path: Path, tiny_model_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = write_session(tmp_path / "s.ses", 150, first_seq=65_520)
    model = str(tiny_model_path)
    assert main(["eval", str(path), "--model", model, "--json", "--batch", "1"]) == 0
    one = json.loads(capsys.readouterr().out)
    assert main(["eval", str(path), "--model", model, "--json", "--batch", "5"]) == 0
    run = capsys.readouterr()
    five = json.loads(run.out)
    assert "peak RSS" in run.err
    assert "frames per CPU s" in run.err
    assert five["rate"]["paired_frames"] == one["rate"]["paired_frames"] == 150
    assert five["step_ms_per_row"]["largest_batch"] == 5
    assert one["step_ms_per_row"]["largest_batch"] == 1
    for key in ("metrics", "per_action", "confusion", "ood", "sessions"):
        assert _rounded(five[key]) == _rounded(one[key]), key
    assert main(["eval", str(path), "--model", model, "--batch", "5"]) == 0
    assert "on up to 5 segments at a time" in capsys.readouterr().out


def test_bad_batch_and_a_truncated_session_are_one_line(
    tmp_path: Path, tiny_model_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = write_session(tmp_path / "s.ses", 60)
    model = str(tiny_model_path)
    assert main(["eval", str(path), "--model", model, "--batch", "0"]) == 2
    err = capsys.readouterr().err
    assert "--batch must be at least 1" in err
    assert err.count("\n") == 1
    cut = tmp_path / "cut.ses"
    cut.write_bytes(path.read_bytes()[:20])  # cut inside the header
    assert main(["eval", str(cut), "--model", model]) == 2
    err = capsys.readouterr().err
    assert "cut short" in err
    assert err.count("\n") == 1


@pytest.mark.usefixtures("small_segments")
def test_a_session_cut_mid_record_replays_alike(tmp_path: Path, tiny_model_path: Path) -> None:
    # Power loss mid-record: the reader stops at the last whole record, both paths alike.
    path = write_session(tmp_path / "s.ses", 200)
    cut = tmp_path / "cut.ses"
    cut.write_bytes(path.read_bytes()[: len(path.read_bytes()) * 2 // 3 + 5])
    runtime = ScottiRuntime(tiny_model_path)
    batched = replay_session(cut, runtime, batch=4)
    assert 60 < batched.pairs < 200
    assert_same_replay(batched, cut, runtime)
    report = evaluate_sessions([cut], runtime, batch=4)
    assert report["rate"]["paired_frames"] == batched.pairs


def _rounded(value: object) -> object:
    """Floats to 4 places (NaN: None), through lists and dicts (a report within float
    tolerance)."""
    if isinstance(value, float):
        return None if math.isnan(value) else round(value, 4)
    if isinstance(value, dict):
        return {k: _rounded(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_rounded(v) for v in value]
    return value


class ThreadRecordingRuntime(ScottiRuntime):
    """The real step graph, noting which threads ran it."""

    def __init__(self, path: Path) -> None:
        super().__init__(path)
        self.threads_seen: set[int] = set()

    def run_steps(self, frames: npt.ArrayLike, past: npt.ArrayLike) -> StepBatch:
        self.threads_seen.add(threading.get_ident())
        return super().run_steps(frames, past)


@pytest.mark.parametrize(("batch", "jobs"), [(3, 2), (4, 3), (64, 2)])
@pytest.mark.usefixtures("small_segments")
def test_segment_groups_on_threads_predict_what_frame_by_frame_predicts(
    tmp_path: Path, tiny_model_path: Path, batch: int, jobs: int
) -> None:
    # As above: a restart mid-session, seqs wrapping; chunks of 100 frames per job cut
    # into jobs groups of batch segments, stepped side by side on threads.
    silent = {(k, foot) for k in range(150, 170) for foot in (0, 1)}
    path = write_session(tmp_path / "gap.ses", 301, first_seq=65_500, drop_foot=silent)
    runtime = ThreadRecordingRuntime(tiny_model_path)
    threaded = replay_session(path, runtime, batch=batch, jobs=jobs)
    assert threading.get_ident() not in runtime.threads_seen  # the pool's threads ran it
    assert len(runtime.threads_seen) > 1
    assert max(n for _, n in threaded.step_batches) <= batch
    assert_same_replay(threaded, path, ScottiRuntime(tiny_model_path))


@pytest.mark.usefixtures("small_segments")
def test_flags_on_threads_count_exactly_as_frame_by_frame(
    tmp_path: Path, calibrated: ScottiRuntime
) -> None:
    path = write_synthetic_session(
        tmp_path / "flags.ses", frames=FLAG_FRAMES, counts_of=_counts
    ).path
    threaded = replay_session(path, calibrated, batch=2, jobs=3)
    assert_same_replay(threaded, path, calibrated)


@pytest.mark.usefixtures("small_segments")
def test_cli_jobs_report_the_same_scores(
    tmp_path: Path, tiny_model_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = write_session(tmp_path / "s.ses", 250, first_seq=65_520)
    model = str(tiny_model_path)
    assert main(["eval", str(path), "--model", model, "--json", "--jobs", "1"]) == 0
    one = json.loads(capsys.readouterr().out)
    assert main(["eval", str(path), "--model", model, "--json", "--jobs", "2", "--batch", "3"]) == 0
    run = capsys.readouterr()
    two = json.loads(run.out)
    assert "2 job(s)" in run.err
    assert (one["rate"]["jobs"], two["rate"]["jobs"]) == (1, 2)
    assert two["step_ms_per_row"]["largest_batch"] == 3
    for key in ("metrics", "per_action", "confusion", "ood", "sessions"):
        assert _rounded(two[key]) == _rounded(one[key]), key
    assert main(["eval", str(path), "--model", model, "--jobs", "0"]) == 2
    err = capsys.readouterr().err
    assert "--jobs must be at least 1" in err
    assert err.count("\n") == 1


def test_sessions_on_threads_report_what_one_thread_reports(
    tmp_path: Path, tiny_model_path: Path
) -> None:
    # Three sessions of different lengths, two replayed at a time with jobs > 1: the same
    # report, sessions in the order given.
    paths = [write_session(tmp_path / f"s{n}.ses", n, first_seq=65_400 + n) for n in (530, 90, 410)]
    runtime = ScottiRuntime(tiny_model_path)
    seen: list[list[str]] = [[], []]
    reports = [
        evaluate_models(
            paths,
            [runtime],
            jobs=jobs,
            on_session=lambda _i, _n, p, _s, k=k: seen[k].append(p.name),
        )[0]
        for k, jobs in enumerate((1, 2))
    ]
    assert seen[0] == seen[1] == ["s530.ses", "s90.ses", "s410.ses"]
    one, two = reports
    assert [s["path"] for s in two["sessions"]] == [str(p) for p in paths]
    for key in ("metrics", "per_action", "confusion", "ood", "sessions", "predictions"):
        assert _rounded(two[key]) == _rounded(one[key]), key
    assert two["rate"]["paired_frames"] == one["rate"]["paired_frames"] == 1030
