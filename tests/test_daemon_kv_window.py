"""The daemon on a streaming-native export: its engine runs the export's own step graph
(a key/value cache per device), batched across devices, and every prediction is the
one ``KvStreamingWindow`` makes pushed frame by frame over the same frame path."""

from __future__ import annotations

import asyncio
import dataclasses
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("torch")
from scotti.daemon.frames.pipeline import Pipeline, Prediction
from scotti.daemon.inference.engine import InferenceEngine, InferenceJob, InferenceResult
from scotti.daemon.inference.window import Window
from scotti.daemon.input.sources import ReplaySource
from scotti.daemon.mqtt.schemas import Info
from scotti.daemon.service.counters import Counters
from scotti.daemon.tools.local_broker import Mosquitto
from scotti.firmware_protocol.frame_path import stream_pairs
from scotti.firmware_protocol.pairing import PairedFrame
from scotti.firmware_protocol.session import PacketRecord, SessionReader
from scotti.models.contract import ACTIONS
from scotti.models.input_checks import OUT_OF_RANGE, UNLOADED
from scotti.models.kv_streaming import KvStepRuntime, KvStreamingWindow, open_step_model
from scotti.models.ood import UNFAMILIAR
from scotti.models.runtime import StepResult

from tests import test_evaluation_kv_segments as kv_eval
from tests.support.broker import collect, payloads, start_daemon
from tests.support.sessions import write_synthetic_session
from tests.test_evaluation_kv_segments import FLAG_FRAMES, _counts

pytestmark = pytest.mark.torch

# Evaluation's OOD-calibrated copy of the tiny streaming-native export (kv_model, the
# shared fixture of tests/support/fixtures_models.py).
calibrated_kv = kv_eval.calibrated_kv

POSE_ATOL = 1e-4
MODEL_FLAGS = (UNLOADED, OUT_OF_RANGE, UNFAMILIAR)  # what a window adds
RESTART_AT = 150  # device 1's window starts over here (a gap, a drop)


def _pairs(path: Path) -> list[PairedFrame]:
    with SessionReader(path) as reader:
        chunks = [(r.t_ns, r.data) for r in reader if isinstance(r, PacketRecord)]
    return list(stream_pairs(chunks))


def _frame_by_frame(runtime: KvStepRuntime, pairs: list[PairedFrame]) -> list[StepResult | None]:
    return [result for result, _ in _frame_by_frame_with_reasons(runtime, pairs)]


def _frame_by_frame_with_reasons(
    runtime: KvStepRuntime, pairs: list[PairedFrame]
) -> list[tuple[StepResult | None, tuple[str, ...]]]:
    """Each frame pushed on its own (float copies: the input checks' cleaning path)."""
    window, made = KvStreamingWindow(runtime), []
    for pair in pairs:
        if pair.restart:
            window.reset()
        result = window.push(pair.counts.astype(np.float32))
        made.append((result, window.reasons if result is not None else ()))
    return made


def test_the_daemon_opens_a_streaming_native_export_by_its_metadata(
    kv_model: Path, calibrated_kv: KvStepRuntime
) -> None:
    assert isinstance(open_step_model(kv_model), KvStepRuntime)
    assert isinstance(open_step_model(calibrated_kv.path), KvStepRuntime)


def test_the_engine_batches_kv_windows_and_predicts_as_frame_by_frame(
    tmp_path: Path, calibrated_kv: KvStepRuntime
) -> None:
    runtime = open_step_model(calibrated_kv.path)
    assert isinstance(runtime, KvStepRuntime)
    sessions = []
    for d in range(2):
        path = tmp_path / f"device{d}.ses"
        write_synthetic_session(path, frames=FLAG_FRAMES, seq_start=37 * d, counts_of=_counts)
        sessions.append(_pairs(path))
    sessions[1][RESTART_AT] = dataclasses.replace(sessions[1][RESTART_AT], restart=True)
    results: list[list[InferenceResult]] = [[], []]
    windows = [Window(runtime) for _ in sessions]

    async def body() -> InferenceEngine:
        engine = InferenceEngine(batch=True)
        lanes = [engine.lane(w, results[d].append, max_queue=10_000) for d, w in enumerate(windows)]
        for lane in lanes:
            lane.start()
        for d, (lane, pairs) in enumerate(zip(lanes, sessions, strict=True)):
            for i, pair in enumerate(pairs):
                lane.submit(InferenceJob(1000 * d + i, pair))
        engine.start()
        for lane in lanes:
            await asyncio.wait_for(lane.wait_below(1), 60)
            await lane.stop()
        await engine.stop()
        return engine

    engine = asyncio.run(body())
    frames = sum(len(p) for p in sessions)
    assert engine.frames == frames
    assert engine.calls == max(len(p) for p in sessions)  # both devices in each call
    assert windows[1].restarts == 1
    flags: set[str] = set()
    reasons: set[str] = set()
    for got, pairs in zip(results, sessions, strict=True):
        want = _frame_by_frame_with_reasons(runtime, pairs)
        assert len(got) == len(want)
        for have, (expected, expected_reasons) in zip(got, want, strict=True):
            assert have.error is None
            assert have.output is not None
            assert have.output.reasons == expected_reasons
            reasons.update(expected_reasons)
            result = have.output.result
            assert (result is None) == (expected is None)
            if result is None or expected is None:
                continue
            np.testing.assert_allclose(result.pose, expected.pose, atol=POSE_ATOL)
            assert int(np.argmax(result.action_probs)) == int(np.argmax(expected.action_probs))
            assert result.flags == expected.flags
            flags.update(result.flags)
    assert {UNLOADED, OUT_OF_RANGE, UNFAMILIAR} <= flags  # the flags were exercised
    assert len(reasons) >= 3  # and the reasons each flag gives
    warm = [r for r in results[1] if r.output is not None and r.output.warming]
    assert len(warm) == 2 * (runtime.window - 1)  # from the start, and again after the restart


def test_pipelines_sharing_an_engine_serve_what_frame_by_frame_predicts(
    tmp_path: Path, calibrated_kv: KvStepRuntime
) -> None:
    """Two devices replayed through the daemon's Pipeline, one engine: the Predictions."""
    paths = [tmp_path / f"replay{d}.ses" for d in range(2)]
    for d, path in enumerate(paths):
        write_synthetic_session(path, frames=FLAG_FRAMES, seq_start=91 * d, counts_of=_counts)
    served: list[list[Prediction]] = [[], []]
    engine = InferenceEngine(batch=True)

    async def go() -> None:
        engine.start()
        pipelines = [
            Pipeline(ReplaySource(path, speed="max"), calibrated_kv, Counters(), engine=engine)
            for path in paths
        ]
        stop = asyncio.Event()
        await asyncio.gather(
            *(p.run(served[d].append, lambda _: None, stop) for d, p in enumerate(pipelines))
        )
        await engine.stop()

    asyncio.run(go())
    assert engine.calls < engine.frames  # frames of both devices shared calls
    flags: set[str] = set()
    for path, predictions in zip(paths, served, strict=True):
        pairs = _pairs(path)
        want = [
            (pair, r)
            for pair, r in zip(pairs, _frame_by_frame(calibrated_kv, pairs), strict=True)
            if r is not None
        ]
        assert len(predictions) == len(want) > 0
        for got, (pair, expected) in zip(predictions, want, strict=True):
            np.testing.assert_array_equal(got.counts, pair.counts)
            np.testing.assert_allclose(got.pose, expected.pose, atol=POSE_ATOL)
            assert int(np.argmax(got.action_probs)) == int(np.argmax(expected.action_probs))
            assert got.unfamiliar_score is not None  # the calibrated model's score
            assert [f for f in got.flags if f in MODEL_FLAGS] == list(expected.flags)
            flags.update(got.flags)
    assert {UNLOADED, OUT_OF_RANGE, UNFAMILIAR} <= flags


@pytest.mark.mosquitto
@pytest.mark.slow
def test_the_daemon_serves_a_streaming_native_export_over_mqtt(
    mosquitto: Mosquitto, calibrated_kv: KvStepRuntime, tmp_path: Path
) -> None:
    """The real daemon, ``--replay --speed max``: it opens the export by its metadata,
    says its step kind in ``info`` and publishes frame-by-frame's poses and actions."""
    path = tmp_path / "served.ses"
    write_synthetic_session(path, frames=FLAG_FRAMES, counts_of=_counts)
    device = "kv-e2e"
    with collect(mosquitto, f"scotti/{device}/#") as got:
        args = ["--replay", str(path), "--speed", "max", "--model", str(calibrated_kv.path)]
        args += ["--broker", mosquitto.url, "--device-id", device]
        daemon = start_daemon(args, tmp_path / "daemon.log")
        assert daemon.wait(60) == 0, daemon.log
        got.wait_for(lambda m: any(s["state"] == "offline" for s in payloads(m, "status")), 5)
    msgs = got.snapshot()
    info = Info.model_validate_json(next(m for m in msgs if m.topic.endswith("/info")).payload)
    assert info.model["graph"] == "step_kv"
    assert info.model["step_kind"] == calibrated_kv.step_kind
    assert info.model["receptive_field"] == calibrated_kv.receptive_field
    pairs = _pairs(path)
    want = {seq: r for seq, r in enumerate(_frame_by_frame(calibrated_kv, pairs)) if r is not None}
    poses = {p["seq"]: p["keypoints"] for p in payloads(msgs, "pose")}
    actions = {a["seq"]: a["probabilities"] for a in payloads(msgs, "action")}
    assert sorted(poses) == sorted(want)
    for seq, expected in want.items():
        np.testing.assert_allclose(np.array(poses[seq]), expected.pose, atol=POSE_ATOL)
        probs = [actions[seq][name] for name in ACTIONS]
        assert int(np.argmax(probs)) == int(np.argmax(expected.action_probs))
