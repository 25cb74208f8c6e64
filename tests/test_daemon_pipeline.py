"""The whole pipeline on the tiny exported model, fed by replayed and live sessions."""

from __future__ import annotations

import asyncio
import dataclasses
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from scotti.daemon.frames.pipeline import Pipeline, PipelineState, Prediction
from scotti.daemon.input.board_emulator import BoardEmulator
from scotti.daemon.input.simulated import SimulatedSource
from scotti.daemon.input.sources import ReplaySource, SerialSource, Source
from scotti.daemon.mqtt.messages import frame_payloads
from scotti.daemon.mqtt.schemas import Action, Progress
from scotti.daemon.service.counters import Counters
from scotti.daemon.waiting import Backoff
from scotti.firmware_protocol.packets import Foot
from scotti.models.contract import (
    ACTIONS,
    FRAME_COLS,
    FRAME_ROWS,
    MAX_COUNT,
    NO_ACTION,
    NUM_ACTIONS,
    NUM_KEYPOINTS,
    STANDING,
)
from scotti.models.input_checks import UNLOADED_FRAMES
from scotti.models.runtime import ScottiRuntime

from tests.support.sessions import synthetic_counts, write_synthetic_session


@pytest.fixture(scope="module")
def runtime(tiny_model_path: Path) -> ScottiRuntime:
    return ScottiRuntime(tiny_model_path)


def run_pipeline(
    source: Source,
    runtime: ScottiRuntime,
    *,
    until: Callable[[list[Prediction], list[PipelineState]], bool] | None = None,
    timeout: float = 30.0,
    **kwargs: object,
) -> tuple[list[Prediction], list[PipelineState], Counters]:
    """Run until the source ends (or ``until`` holds); return what came out."""
    predictions: list[Prediction] = []
    states: list[PipelineState] = []
    counters = Counters()

    async def body() -> None:
        stop = asyncio.Event()
        pipeline = Pipeline(source, runtime, counters, **kwargs)  # type: ignore[arg-type]

        def on_prediction(p: Prediction) -> None:
            predictions.append(p)
            if until is not None and until(predictions, states):
                stop.set()

        def on_state(s: PipelineState) -> None:
            states.append(s)
            if until is not None and until(predictions, states):
                stop.set()

        await asyncio.wait_for(pipeline.run(on_prediction, on_state, stop), timeout)

    asyncio.run(body())
    return predictions, states, counters


def test_replay_predicts_from_the_t_th_frame_on_with_continuous_seqs(
    tmp_path: Path, runtime: ScottiRuntime
) -> None:
    frames = runtime.window + 20
    session = write_synthetic_session(tmp_path / "s.scotti", frames=frames, garbage_every=5)
    predictions, states, counters = run_pipeline(ReplaySource(session.path, speed="max"), runtime)
    t = runtime.window
    assert len(predictions) == frames - t + 1
    assert [p.seq for p in predictions] == list(range(t - 1, frames))
    first = predictions[0]
    assert (first.left_seq, first.right_seq) == (t - 1, t - 1)
    assert first.pose.shape == (NUM_KEYPOINTS, 3)
    assert first.action_probs.shape == (NUM_ACTIONS,)
    assert abs(float(first.action_probs.sum()) - 1.0) < 1e-4
    assert 0 <= first.action < NUM_ACTIONS
    assert first.flags == ()
    assert first.predicted_for_mono_ns == first.last_byte_mono_ns + 62_500_000
    assert first.host_mono_ns >= first.last_byte_mono_ns
    # The state walked through warming up to (T, T) and ended disconnected.
    warming = [s.warming for s in states]
    assert (t - 1, t) in warming
    assert warming[-1] == (t, t)
    assert states[0].source == "disconnected"
    assert any(s.source == "connected" for s in states)
    assert states[-1].reasons == ("receiver disconnected: end of replay",)
    snap = counters.snapshot()
    assert snap["frames_in"] == {"left": frames, "right": frames}
    assert snap["predictions"] == len(predictions)
    assert snap["dropped_frames"] == 0
    bad = snap["bad_packets"]
    assert bad["bad_cobs"] + bad["bad_crc"] + bad["malformed"] >= frames // 5  # the garbage
    assert snap["latency_ms"]["inference"]["n"] == frames


def test_a_prediction_is_a_whole_frozen_prediction(tmp_path: Path, runtime: ScottiRuntime) -> None:
    session = write_synthetic_session(tmp_path / "s.scotti", frames=runtime.window + 2)
    prediction = run_pipeline(ReplaySource(session.path, speed="max"), runtime)[0][-1]
    assert list(vars(prediction)) == [f.name for f in dataclasses.fields(Prediction)]
    assert prediction.unfamiliar_score is None or prediction.unfamiliar_score >= 0.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        prediction.seq = 0  # type: ignore[misc]


def test_replaying_the_same_session_twice_gives_identical_predictions(
    tmp_path: Path, runtime: ScottiRuntime
) -> None:
    session = write_synthetic_session(tmp_path / "s.scotti", frames=runtime.window + 8)
    runs = [run_pipeline(ReplaySource(session.path, speed="max"), runtime)[0] for _ in range(2)]
    assert len(runs[0]) == len(runs[1]) == 9
    for a, b in zip(*runs, strict=True):
        assert a.seq == b.seq
        assert np.array_equal(a.pose, b.pose)
        assert np.array_equal(a.action_probs, b.action_probs)
        assert a.progress == b.progress or (np.isnan(a.progress) and np.isnan(b.progress))
        assert a.repetition == b.repetition


def test_while_the_model_says_standing_progress_is_null_and_nothing_is_counted(
    tmp_path: Path, standing_model_path: Path
) -> None:
    runtime = ScottiRuntime(standing_model_path)
    session = write_synthetic_session(tmp_path / "s.scotti", frames=runtime.window + 24)
    predictions, _, _ = run_pipeline(ReplaySource(session.path, speed="max"), runtime)
    assert len(predictions) == 25
    assert all(p.action == STANDING for p in predictions)
    assert all(np.isnan(p.progress) for p in predictions)
    assert all(p.repetition == -1 for p in predictions)
    topics = dict(frame_payloads(predictions[-1], latency_ms=1.0))
    action, progress = topics["action"], topics["progress"]
    assert isinstance(action, Action)
    assert isinstance(progress, Progress)
    assert action.action == "standing"
    assert action.confidence > 0.99
    assert set(action.probabilities) == set(ACTIONS)
    assert progress.action == "standing"
    assert progress.progress is None
    assert progress.repetition == -1
    assert '"progress":null' in progress.model_dump_json()


def test_a_silent_foot_degrades_the_state_and_flags_predictions(
    tmp_path: Path, runtime: ScottiRuntime
) -> None:
    from scotti.firmware_protocol.packets import Foot

    session = write_synthetic_session(
        tmp_path / "left.scotti", frames=runtime.window + 12, feet=(Foot.LEFT,)
    )
    predictions, states, _ = run_pipeline(ReplaySource(session.path, speed="max"), runtime)
    assert predictions
    assert all("right_filled" in p.flags for p in predictions)
    assert any("right insole silent" in s.reasons for s in states)
    assert all(p.right_seq == -1 for p in predictions)


def test_live_board_through_a_pty_then_unplug_restarts_the_window(
    board_factory: Callable[..., BoardEmulator], tmp_path: Path, runtime: ScottiRuntime
) -> None:
    t = runtime.window
    session = write_synthetic_session(tmp_path / "live.scotti", frames=3 * t + 10)
    board = board_factory(session, speed=8.0)
    source = SerialSource(str(board.link), backoff=Backoff(initial_s=0.02, cap_s=0.2))
    unplugged = False

    def warmed_again(predictions: list[Prediction]) -> int | None:
        """Index of the first prediction after a jump of T seqs (the window refilled)."""
        seqs = [p.seq for p in predictions]
        return next((i for i in range(1, len(seqs)) if seqs[i] - seqs[i - 1] >= t), None)

    def until(predictions: list[Prediction], states: list[PipelineState]) -> bool:
        nonlocal unplugged
        if len(predictions) == 3 and not unplugged:
            unplugged = True
            board.unplug()
            board.replug()
        cut = warmed_again(predictions)
        return cut is not None and len(predictions) >= cut + 3

    predictions, states, counters = run_pipeline(source, runtime, until=until)
    assert counters.reconnects >= 1
    assert any(s.source == "disconnected" for s in states[1:])
    # Frames read before the cut are still predicted (consecutive seqs); after the
    # reconnect the window warmed up again from zero: T more frames, then consecutive.
    cut = warmed_again(predictions)
    assert cut is not None
    seqs = [p.seq for p in predictions]
    assert seqs[:cut] == list(range(seqs[0], seqs[0] + cut))
    assert seqs[cut:] == list(range(seqs[cut], seqs[cut] + len(seqs) - cut))
    assert counters.window_restarts >= 1


def test_the_simulated_demo_source_runs_the_live_path(
    tmp_path: Path, runtime: ScottiRuntime
) -> None:
    from tests.test_daemon_sources import SHORT_SCENE

    scene = tmp_path / "short.toml"
    scene.write_text(SHORT_SCENE)

    def until(predictions: list[Prediction], _: list[PipelineState]) -> bool:
        return len(predictions) >= 5

    predictions, states, counters = run_pipeline(
        SimulatedSource(scene, speed=4.0), runtime, until=until
    )
    assert len(predictions) >= 5
    assert predictions[0].seq == runtime.window - 1
    assert states[-1].source == "connected"
    assert counters.snapshot()["frames_in"]["left"] >= runtime.window


def test_each_prediction_carries_its_input_frame_read_only(
    tmp_path: Path, runtime: ScottiRuntime
) -> None:
    from scotti.firmware_protocol.packets import Foot

    from tests.support.sessions import synthetic_counts

    session = write_synthetic_session(tmp_path / "c.scotti", frames=runtime.window + 6)
    predictions, _, _ = run_pipeline(ReplaySource(session.path, speed="max"), runtime)
    assert len(predictions) == 7
    for p in predictions:
        expected = np.concatenate(
            [synthetic_counts(Foot.LEFT, p.left_seq), synthetic_counts(Foot.RIGHT, p.right_seq)],
            axis=1,
        )
        assert p.counts.dtype == np.uint16
        np.testing.assert_array_equal(p.counts, expected)  # the newest frame, left|right
        assert not p.counts.flags.writeable
        with pytest.raises(ValueError, match="read-only"):
            p.counts[0, 0] = 1


def test_after_a_replug_the_state_warms_up_from_zero_before_reading_ready(
    board_factory: Callable[..., BoardEmulator], tmp_path: Path, runtime: ScottiRuntime
) -> None:
    t = runtime.window
    session = write_synthetic_session(tmp_path / "replug.scotti", frames=3 * t + 10)
    board = board_factory(session, speed=8.0)
    source = SerialSource(str(board.link), backoff=Backoff(initial_s=0.02, cap_s=0.2))
    unplugged_at: int | None = None  # how many states had been seen at the unplug

    def until(predictions: list[Prediction], states: list[PipelineState]) -> bool:
        nonlocal unplugged_at
        if len(predictions) == 3 and unplugged_at is None:
            unplugged_at = len(states)
            board.unplug()
            board.replug()
        # Frames read before the cut are still predicted (before the cut is reported):
        # run on until the reconnected window is full again.
        return unplugged_at is not None and any(
            s.source == "connected" and s.warming == (t, t) for s in states[unplugged_at + 1 :]
        )

    predictions, states, _ = run_pipeline(source, runtime, until=until)
    assert unplugged_at is not None
    assert len(predictions) >= 4
    assert states[unplugged_at - 1].warming == (t, t)  # warmed up before the unplug
    after = states[unplugged_at:]
    cut = next(i for i, s in enumerate(after) if s.source == "disconnected")
    back = [s for s in after[cut:] if s.source == "connected"]
    assert back, "never reconnected"
    assert back[0].warming == (0, t)  # reconnected: still empty, not the old (T, T)
    ready = next(i for i, s in enumerate(back) if s.warming == (t, t))
    assert [s.warming[0] for s in back[:ready]] == sorted(s.warming[0] for s in back[:ready])


def test_an_empty_insole_pair_withholds_action_progress_and_counting_while_it_lasts(
    tmp_path: Path, runtime: ScottiRuntime
) -> None:
    """Frames 60..89 read zero (nobody on the insoles): once 16 of them are the newest
    frames, predictions are flagged unloaded with no action, no progress and no count,
    and status says why; when the person steps back on, both clear."""
    empty_from, empty_to = 60, 90

    def counts(foot: Foot, seq: int, i: int) -> np.ndarray:
        if empty_from <= i < empty_to:
            return np.zeros((FRAME_ROWS, FRAME_COLS), np.uint16)
        return synthetic_counts(foot, seq)

    session = write_synthetic_session(tmp_path / "off.scotti", frames=130, counts_of=counts)
    predictions, states, _ = run_pipeline(ReplaySource(session.path, speed="max"), runtime)
    by_seq = {p.seq: p for p in predictions}
    assert len(by_seq) == 130 - runtime.window + 1
    first_unloaded = empty_from + UNLOADED_FRAMES - 1  # the 16th empty frame is the newest
    for seq, p in by_seq.items():
        unloaded = first_unloaded <= seq < empty_to
        assert ("unloaded" in p.flags) == unloaded, seq
        assert np.isfinite(p.pose).all()
        if unloaded:
            assert (p.action, p.withheld, p.repetition) == (NO_ACTION, "unloaded", -1)
            assert np.isnan(p.progress)
            payloads = dict(frame_payloads(p, 1.0))
            action, progress = payloads["action"], payloads["progress"]
            assert isinstance(action, Action)
            assert isinstance(progress, Progress)
            assert (action.action, action.confidence, action.withheld) == (None, 0.0, "unloaded")
            assert (progress.progress, progress.repetition) == (None, -1)
        else:
            assert p.withheld is None
            assert 0 <= p.action < NUM_ACTIONS
    said = [s for s in states if any(r.startswith("unloaded: ") for r in s.reasons)]
    assert said, [s.reasons for s in states]
    assert not any(r.startswith("unloaded") for r in states[-1].reasons)


def test_noise_on_the_line_is_out_of_range_with_its_reason(
    tmp_path: Path, runtime: ScottiRuntime
) -> None:
    """Full-scale uniform noise on both insoles, the whole session: every prediction is
    flagged out_of_range (load outside the outline, more force than a landing)."""

    def noise(foot: Foot, seq: int, i: int) -> np.ndarray:
        rng = np.random.default_rng(seq * 2 + int(foot))
        return rng.integers(0, MAX_COUNT + 1, (FRAME_ROWS, FRAME_COLS), dtype=np.uint16)

    session = write_synthetic_session(tmp_path / "noise.scotti", frames=60, counts_of=noise)
    predictions, states, _ = run_pipeline(ReplaySource(session.path, speed="max"), runtime)
    assert predictions
    assert all(p.withheld == "out_of_range" and p.action == NO_ACTION for p in predictions)
    reasons = [r for s in states for r in s.reasons if r.startswith("out_of_range: ")]
    assert reasons
    assert "load outside the insole outline" in reasons[-1]
