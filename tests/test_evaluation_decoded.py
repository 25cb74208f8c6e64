"""A session decoded into blocks of pairs (``evaluation.decoded``): the blocks hold
the pairs the one frame path gives pair by pair, and a replay whose file is decoded
in a worker process reports what a replay decoding here reports; a broken file is
the same one-line error, and a worker left mid-session is replaced."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scotti.cli.main import main
from scotti.evaluation import decoded, segments
from scotti.evaluation.decoded import DecodeWorker, PairBlock, SessionEnd, decode_session
from scotti.evaluation.errors import EvaluationError
from scotti.evaluation.evaluation import decode_where, evaluate_models
from scotti.evaluation.replay import replay_session_models
from scotti.firmware_protocol.errors import SessionError
from scotti.firmware_protocol.frame_path import PairSeq, stream_pairs
from scotti.firmware_protocol.session import LabelRecord, PacketRecord, SessionReader
from scotti.models.kv_streaming import open_step_model

from tests.support.export_sessions import write_session
from tests.test_evaluation_segments import _rounded

SCORED = ("metrics", "per_action", "confusion", "ood", "sessions", "predictions")


def _gappy(path: Path, frames: int = 301) -> Path:
    """Seqs that wrap, a foot silent long enough to be filled, both feet silent past
    a restart, and junk bytes on the line: every flag a block carries."""
    silent = {(k, foot) for k in range(150, 170) for foot in (0, 1)}
    silent |= {(k, 1) for k in range(60, 75)}
    return write_session(path, frames, first_seq=65_500, drop_foot=silent, garbage_every=50)


def _items(path: Path, block_pairs: int) -> tuple[list[PairBlock], SessionEnd]:
    items = list(decode_session(path, block_pairs=block_pairs))
    end = items.pop()
    assert isinstance(end, SessionEnd)
    assert all(isinstance(b, PairBlock) for b in items)
    return items, end  # type: ignore[return-value]


def test_blocks_hold_the_pairs_of_the_frame_path(tmp_path: Path) -> None:
    path = _gappy(tmp_path / "gappy.ses")
    with SessionReader(path) as reader:
        records = list(reader)
    chunks = [(r.t_ns, r.data) for r in records if isinstance(r, PacketRecord)]
    pairs, clock = list(stream_pairs(chunks)), PairSeq()
    exts = [clock.of(p) for p in pairs]
    blocks, end = _items(path, block_pairs=7)
    assert max(len(b) for b in blocks) < 7 + 4  # a read's pairs go whole into one block
    assert len(blocks) > 20
    np.testing.assert_array_equal(
        np.concatenate([b.counts for b in blocks]), [p.counts for p in pairs]
    )
    restart = np.concatenate([b.restart for b in blocks])
    assert restart.tolist() == [p.restart for p in pairs]
    assert restart[1:].any()  # the long silence restarted the window
    degraded = np.concatenate([b.degraded for b in blocks])
    assert degraded.tolist() == [bool(p.flags) for p in pairs]
    assert degraded.any()
    ext = np.concatenate([b.ext for b in blocks])
    known = np.concatenate([b.has_ext for b in blocks])
    assert [int(e) if k else None for e, k in zip(ext, known, strict=True)] == exts
    labels = [lb for b in blocks for lb in b.labels] + end.labels
    assert [lb.seq for lb in labels] == [r.seq for r in records if isinstance(r, LabelRecord)]
    assert end.subject == {"id": "s1"}
    assert end.decode_errors > 0  # the junk
    assert end.silent_pairs["right"] > 0
    assert end.silent_pairs == {
        foot: sum(f"{foot}_filled" in p.flags for p in pairs) for foot in ("left", "right")
    }


def test_a_replay_decoded_in_a_worker_reports_what_one_decoded_here_reports(
    tmp_path: Path, tiny_model_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Small blocks and chunks: the tracks take many blocks, across chunk boundaries.
    monkeypatch.setattr(decoded, "BLOCK_PAIRS", 16)
    monkeypatch.setattr(segments, "MIN_SEGMENT_FRAMES", 1)
    monkeypatch.setattr(segments, "CHUNK_FRAMES", 100)
    monkeypatch.setattr(segments, "STREAMED_CHUNK_FRAMES", 90)
    path = _gappy(tmp_path / "gappy.ses", 420)
    runtime = open_step_model(tiny_model_path)
    here = replay_session_models(path, [runtime], batch=4)[0]
    with DecodeWorker() as worker:
        there = replay_session_models(path, [runtime], batch=4, jobs=2, decoder=worker)[0]
        again = replay_session_models(path, [runtime], batch=4, decoder=worker)[0]
    assert here.window_restarts == 1
    for replay in (there, again):
        assert replay.summary() == here.summary()
        assert [m.ext for m in replay.made] == [m.ext for m in here.made]
        assert [m.flags for m in replay.made] == [m.flags for m in here.made]
        for ours, theirs in zip(replay.made, here.made, strict=True):
            np.testing.assert_allclose(ours.probs, theirs.probs, atol=1e-5)
        assert replay.subject == here.subject == "s1"
        assert replay.decode_errors == here.decode_errors > 0
        assert replay.decode_cpu_s > 0


def test_evaluate_models_decoding_in_processes_reports_alike(
    tmp_path: Path, tiny_model_path: Path, standing_model_path: Path
) -> None:
    paths = [write_session(tmp_path / f"s{n}.ses", n, first_seq=65_400 + n) for n in (530, 90, 410)]
    runtimes = [open_step_model(tiny_model_path), open_step_model(standing_model_path)]
    here = evaluate_models(paths, runtimes, jobs=2, decode="here")
    there = evaluate_models(paths, runtimes, jobs=2, decode="process")
    for mine, theirs in zip(there, here, strict=True):
        for key in SCORED:
            assert _rounded(mine[key]) == _rounded(theirs[key]), key
        assert mine["rate"]["decode"] == "process"
        assert theirs["rate"]["decode"] == "here"
    assert there[0]["actions_predicted"] != there[1]["actions_predicted"]
    sampled = evaluate_models(paths, runtimes[:1], every=4, decode="process", jobs=2)[0]
    assert _rounded(sampled["metrics"]) == _rounded(
        evaluate_models(paths, runtimes[:1], every=4, decode="here")[0]["metrics"]
    )


def test_a_broken_file_in_the_worker_is_the_error_here_and_the_worker_goes_on(
    tmp_path: Path,
) -> None:
    good = write_session(tmp_path / "good.ses", 120)
    cut = tmp_path / "cut.ses"
    cut.write_bytes(good.read_bytes()[:20])  # cut inside the header
    with pytest.raises(SessionError) as here:
        list(decode_session(cut))
    with DecodeWorker() as worker:
        with pytest.raises(SessionError) as there:
            list(worker.blocks(cut))
        assert str(there.value) == str(here.value)
        process = worker._process
        blocks, _ = _items(good, 512)
        from_worker = list(worker.blocks(good))
        assert worker._process is process  # the same worker read the next file
    assert sum(len(b) for b in from_worker[:-1]) == sum(len(b) for b in blocks) == 120


def test_a_session_left_mid_way_stops_its_worker_and_the_next_starts_one(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(decoded, "BLOCK_PAIRS", 16)  # not seen by the worker: 512 there
    path = write_session(tmp_path / "s.ses", 1200)
    worker = DecodeWorker().start()
    try:
        first = worker._process
        items = worker.blocks(path)
        assert len(next(items)) == 512
        items.close()  # the replay failed: the rest of the session is not wanted
        assert first is not None
        assert first.poll() is not None  # stopped
        assert worker._process is None
        rest = list(worker.blocks(path))
        assert worker._process is not None
        assert worker._process is not first
        assert sum(len(b) for b in rest if isinstance(b, PairBlock)) == 1200
    finally:
        worker.close()


def test_a_worker_that_dies_is_one_error(tmp_path: Path) -> None:
    path = write_session(tmp_path / "s.ses", 2000)
    worker = DecodeWorker().start()
    assert worker._process is not None
    worker._process.kill()
    worker._process.wait()
    with pytest.raises(EvaluationError, match=r"decoding process ended while reading s\.ses"):
        list(worker.blocks(path))
    worker.close()


def test_where_auto_decodes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = write_session(tmp_path / "s.ses", 100)
    size = path.stat().st_size
    monkeypatch.setattr("scotti.evaluation.evaluation.AUTO_DECODE_BYTES", size)
    assert decode_where("auto", [path], jobs=2, processes=1) == "process"
    assert decode_where("auto", [path], jobs=1, processes=1) == "here"  # no core to spare
    assert decode_where("auto", [path], jobs=2, processes=2) == "here"  # workers decode
    assert decode_where("process", [path], jobs=1, processes=1) == "process"
    assert decode_where("process", [path], jobs=1, processes=2) == "here"
    monkeypatch.setattr("scotti.evaluation.evaluation.AUTO_DECODE_BYTES", size + 1)
    assert decode_where("auto", [path], jobs=2, processes=1) == "here"  # too short to pay
    assert decode_where("auto", [tmp_path / "gone.ses"], jobs=2, processes=1) == "here"
    with pytest.raises(EvaluationError, match="--decode must be one of"):
        decode_where("thread", [path], jobs=2, processes=1)


def test_cli_decode_process(
    tmp_path: Path, tiny_model_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = _gappy(tmp_path / "gappy.ses")
    model = str(tiny_model_path)
    reports = []
    for where in ("here", "process"):
        assert main(["eval", str(path), "--model", model, "--json", "--decode", where]) == 0
        run = capsys.readouterr()
        reports.append(json.loads(run.out))
        assert ("decoded in a process of its own" in run.err) is (where == "process")
    assert reports[1]["rate"]["decode"] == "process"
    for report in reports:  # the decoding's own CPU, part of the whole
        assert 0 < report["rate"]["decode_cpu_seconds"] < report["rate"]["cpu_seconds"]
    for key in SCORED:
        assert _rounded(reports[1][key]) == _rounded(reports[0][key]), key
    cut = tmp_path / "cut.ses"
    cut.write_bytes(path.read_bytes()[:20])
    assert main(["eval", str(cut), "--model", model, "--decode", "process"]) == 2
    err = capsys.readouterr().err
    assert "cut short" in err
    assert err.count("\n") == 1
