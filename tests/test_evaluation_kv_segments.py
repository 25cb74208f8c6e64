"""``scotti eval`` on a streaming-native export (``evaluation.kv_segments``): its own
step graph with a key/value cache per segment, K segments per call, makes the
predictions of a ``KvStreamingWindow`` pushed frame by frame, and reports the paper
form's counts on the same session."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("torch")
import onnx
from scotti.cli.main import main
from scotti.evaluation import segments
from scotti.evaluation.evaluation import SessionReplay, evaluate_sessions, replay_session
from scotti.evaluation.kv_segments import KvSegmentTrack
from scotti.evaluation.sampling import Prediction
from scotti.firmware_protocol.frame_path import FramePath, PairSeq, stream_pairs
from scotti.firmware_protocol.packets import Foot
from scotti.firmware_protocol.session import PacketRecord, SessionReader
from scotti.models.contract import MAX_COUNT, META_OOD
from scotti.models.input_checks import OUT_OF_RANGE, UNLOADED
from scotti.models.kv_streaming import KvCache, KvStepRuntime, KvStreamingWindow, open_step_model
from scotti.models.ood import UNFAMILIAR, OodStats, flag_shares
from scotti.models.runtime import ScottiRuntime, window_graph_for

from tests.support.export_sessions import write_session
from tests.support.sessions import synthetic_counts, write_synthetic_session
from tests.test_export_streaming_native import TINY_KV

pytestmark = pytest.mark.torch

POSE_ATOL = 1e-4


@pytest.fixture
def small_segments(monkeypatch: pytest.MonkeyPatch) -> None:
    """Segments of a few frames and chunks of 100 (the chunk holds 2 receptive fields at
    least): a session is cut many times and crosses chunk boundaries."""
    monkeypatch.setattr(segments, "MIN_SEGMENT_FRAMES", 1)
    monkeypatch.setattr(segments, "CHUNK_FRAMES", 100)


def _pairs(path: Path) -> list[tuple[int | None, bool, np.ndarray]]:
    with SessionReader(path) as reader:
        chunks = [(r.t_ns, r.data) for r in reader if isinstance(r, PacketRecord)]
    seq = PairSeq()
    return [(seq.of(p), p.restart, p.counts) for p in stream_pairs(chunks)]


def frame_by_frame(path: Path, runtime: KvStepRuntime) -> list[Prediction]:
    """One ``KvStreamingWindow`` pushed pair by pair, reset at each restart (the daemon)."""
    window, made = KvStreamingWindow(runtime), []
    for ext, restart, counts in _pairs(path):
        if restart:
            window.reset()
        result = window.push(counts)
        if result is not None and ext is not None:
            made.append(
                Prediction(ext + 1, result.pose, result.action_probs, result.progress, result.flags)
            )
    return made


def assert_same_as_frame_by_frame(
    batched: SessionReplay, path: Path, runtime: KvStepRuntime
) -> None:
    made = frame_by_frame(path, runtime)
    assert [m.ext for m in batched.made] == [m.ext for m in made]
    assert [m.flags for m in batched.made] == [m.flags for m in made]
    for ours, theirs in zip(batched.made, made, strict=True):
        np.testing.assert_allclose(ours.pose, theirs.pose, atol=POSE_ATOL)
        assert np.argmax(ours.probs) == np.argmax(theirs.probs)
        assert ours.progress == pytest.approx(theirs.progress, abs=POSE_ATOL)
    assert flag_shares([m.flags for m in batched.made]) == flag_shares([m.flags for m in made])


@pytest.mark.parametrize("batch", [1, 4, 16])
@pytest.mark.usefixtures("small_segments")
def test_kv_segments_predict_what_the_window_pushed_frame_by_frame_predicts(
    tmp_path: Path, kv_model: Path, batch: int
) -> None:
    # 420 frames, seqs wrapping, both feet silent for 20 frames: the window restarts
    # mid-session, and the cache must forget what came before (unlike the paper form's):
    # at batch 1 one segment steps across the restart and scores the frames after it.
    silent = {(k, foot) for k in range(250, 270) for foot in (0, 1)}
    path = write_session(tmp_path / "gap.ses", 420, first_seq=65_500, drop_foot=silent)
    runtime = open_step_model(kv_model)
    assert isinstance(runtime, KvStepRuntime)
    assert runtime.receptive_field == 118
    batched = replay_session(path, runtime, batch=batch)
    assert batched.window_restarts == 1
    assert len(batched.made) > 300
    assert_same_as_frame_by_frame(batched, path, runtime)
    assert max(n for _, n in batched.step_batches) == batch
    # Threads stepping groups of segments: the same predictions again.
    on_threads = replay_session(path, runtime, batch=batch, jobs=2)
    assert_same_as_frame_by_frame(on_threads, path, runtime)


def test_a_segment_that_starts_cold_would_differ(tmp_path: Path, kv_model: Path) -> None:
    # The check above can fail: with the paper form's warm-up (T-1 frames) a segment's
    # first predictions miss the history their rows read.
    path = write_session(tmp_path / "s.ses", 400)
    runtime = KvStepRuntime(kv_model)

    class TooShort(KvSegmentTrack):
        def history(self) -> int:
            return self.runtime.window - 1

    track = TooShort(runtime, SessionReplay(str(path), "s1"), 4, min_segment=1)
    made = frame_by_frame(path, runtime)
    stream = {m.ext: m.pose for m in made}
    frame_path, clock = FramePath(), PairSeq()
    with SessionReader(path) as reader:
        for record in reader:
            if isinstance(record, PacketRecord):
                for pair in frame_path.feed(record.data, record.t_ns):
                    track.take(pair, clock.of(pair))
    for pair in frame_path.end():
        track.take(pair, clock.of(pair))
    track.finish()
    worst = max(float(np.abs(m.pose - stream[m.ext]).max()) for m in track.made)
    assert worst > 10 * POSE_ATOL


@pytest.fixture(scope="module")
def calibrated_kv(kv_model: Path, tmp_path_factory: pytest.TempPathFactory) -> KvStepRuntime:
    """The kv step graph with OOD statistics whose threshold halves its streamed pooled
    vectors' norms on the flags session: some predictions unfamiliar, some not."""
    plain = KvStepRuntime(kv_model)
    cache = KvCache(plain.window - 1, plain.slots, plain.embed_dim)
    norms = []
    for i in range(FLAG_FRAMES):
        frame = _counts_pair(i).astype(np.float32)[None]
        step = plain.run_steps(frame, cache.past()[None], cache.valid()[None])
        cache.push(step.embedding[0])
        assert step.pooled is not None
        if i >= plain.window - 1:
            norms.append(float(np.linalg.norm(step.pooled[0])))
    e = plain.embed_dim
    stats = OodStats(np.zeros(e, np.float32), np.eye(e, dtype=np.float32), float(np.median(norms)))
    model = onnx.load(str(kv_model))
    model.metadata_props.add(key=META_OOD, value=stats.to_json())
    out = tmp_path_factory.mktemp("kv-calibrated") / "kv-cal.onnx"
    onnx.save(model, str(out))
    return KvStepRuntime(out)


FLAG_FRAMES = 330


def _counts(foot: Foot, seq: int, i: int) -> np.ndarray:
    """A plausible map, then nobody on the insoles (unloaded), then saturated (out_of_range)."""
    if 160 <= i < 210:
        return np.zeros((32, 22), np.uint16)
    if 250 <= i < 270:
        return np.full((32, 22), MAX_COUNT, np.uint16)
    return synthetic_counts(foot, seq)


def _counts_pair(i: int) -> np.ndarray:
    return np.concatenate([_counts(Foot.LEFT, i, i), _counts(Foot.RIGHT, i, i)], axis=1)


@pytest.mark.usefixtures("small_segments")
def test_flags_count_exactly_as_frame_by_frame(
    tmp_path: Path, calibrated_kv: KvStepRuntime
) -> None:
    path = tmp_path / "flags.ses"
    write_synthetic_session(path, frames=FLAG_FRAMES, counts_of=_counts)
    batched = replay_session(path, calibrated_kv, batch=5)
    assert_same_as_frame_by_frame(batched, path, calibrated_kv)
    flags = batched.flags
    assert flags[UNLOADED]
    assert flags[OUT_OF_RANGE]
    assert 0 < flags[UNFAMILIAR] < len(batched.made)


def test_cli_scores_the_kv_form_with_the_paper_forms_counts(
    tmp_path: Path, kv_model: Path, tiny_model_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = write_session(tmp_path / "s.ses", 300, first_seq=65_520)
    assert ScottiRuntime(tiny_model_path).window == TINY_KV.window  # same T: same counts
    assert main(["eval", str(path), "--model", str(kv_model), "--json", "--jobs", "1"]) == 0
    kv = json.loads(capsys.readouterr().out)
    assert main(["eval", str(path), "--model", str(tiny_model_path), "--json", "--jobs", "1"]) == 0
    paper = json.loads(capsys.readouterr().out)
    assert kv["graph"] == paper["graph"] == "step"
    assert kv["model"]["step_kind"] == "kv_cache"
    assert kv["model"]["receptive_field"] == 118
    assert "step_kind" not in paper["model"]
    for key in ("predictions", "pairs", "degraded_pairs"):
        assert kv[key] == paper[key], key
    assert kv["metrics"]["frames"] == paper["metrics"]["frames"] > 200
    for name in ("labels", "predictions", "evaluated", "unlabelled", "window_restarts"):
        assert kv["sessions"][0][name] == paper["sessions"][0][name], name
    for figure in ("mpjpe_mm", "action_accuracy", "progress_mse", "app"):
        assert kv["metrics"][figure] is not None, figure
    # The report's figures are the replay's: the same through the library.
    direct = evaluate_sessions([path], KvStepRuntime(kv_model))
    assert direct["metrics"]["frames"] == kv["metrics"]["frames"]
    assert direct["metrics"]["mpjpe_mm"] == pytest.approx(kv["metrics"]["mpjpe_mm"], abs=1e-3)
    assert main(["eval", str(path), "--model", str(kv_model)]) == 0
    text = capsys.readouterr().out
    assert "MPJPE" in text
    assert "batched streaming (the step graph)" in text


def test_cli_every_k_scores_the_kv_form_through_its_window_graph(
    tmp_path: Path, kv_model: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = write_session(tmp_path / "s.ses", 300)
    assert main(["eval", str(path), "--model", str(kv_model), "--json", "--every", "4"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["graph"] == "window"
    assert report["model"]["window_graph"]["path"] == str(window_graph_for(kv_model))
    assert 60 < report["predictions"] < 80
    alone = tmp_path / "alone.onnx"
    shutil.copy(kv_model, alone)  # no window graph next to it: one line, exit 2
    assert main(["eval", str(path), "--model", str(alone), "--every", "4"]) == 2
    err = capsys.readouterr().err
    assert "no window graph alone.window.onnx" in err
    assert err.count("\n") == 1
