"""The window, the inference worker, repetitions and counters."""

from __future__ import annotations

import asyncio
import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scotti.daemon.inference.engine import (
    InferenceEngine,
    InferenceJob,
    InferenceResult,
    InferenceWorker,
)
from scotti.daemon.inference.repetitions import RepetitionCounter
from scotti.daemon.inference.window import Window
from scotti.daemon.service.counters import Counters, LatencyRing
from scotti.firmware_protocol.pairing import PairedFrame
from scotti.models.contract import ACTIONS, FRAME_COLS, FRAME_ROWS, MAX_COUNT, STANDING
from scotti.models.runtime import ScottiRuntime


@pytest.fixture(scope="module")
def runtime(tiny_model_path: Path) -> ScottiRuntime:
    return ScottiRuntime(tiny_model_path)


def paired(i: int, restart: bool = False) -> PairedFrame:
    rng = np.random.default_rng(i)
    counts = rng.integers(0, MAX_COUNT + 1, size=(FRAME_ROWS, 2 * FRAME_COLS), dtype=np.uint16)
    return PairedFrame(counts, (i, i), (i, i), i, restart=restart)


def test_the_window_predicts_from_the_t_th_frame_and_warms_again_after_restart(
    runtime: ScottiRuntime,
) -> None:
    window = Window(runtime)
    t = window.needed
    outputs = [window.push(paired(i).counts) for i in range(t + 2)]
    assert [o.warming for o in outputs] == [True] * (t - 1) + [False] * 3
    assert outputs[t - 2].frames_in_window == t - 1
    assert outputs[t - 1].frames_in_window == t
    window.restart()
    assert window.restarts == 1
    again = window.push(paired(99).counts)
    assert again.warming
    assert again.frames_in_window == 1


def test_the_window_gives_what_the_runtime_gives_on_the_same_frames(
    runtime: ScottiRuntime, tiny_window_model_path: Path
) -> None:
    window = Window(runtime)
    t = window.needed
    frames = np.stack([paired(i).counts for i in range(t)]).astype(np.float32)
    last = [window.push(f.astype(np.uint16)) for f in frames][-1].result
    assert last is not None
    batch = ScottiRuntime(tiny_window_model_path).run_windows(frames[None])
    np.testing.assert_allclose(last.pose, batch.pose[0], atol=1e-4)
    np.testing.assert_allclose(last.action_probs, batch.action_probs[0], atol=1e-4)


def test_a_worker_that_falls_behind_drops_oldest_and_restarts_without_blocking_the_loop(
    runtime: ScottiRuntime,
) -> None:
    results: list[InferenceResult] = []

    async def body() -> tuple[int, float]:
        worker = InferenceWorker(Window(runtime), results.append, max_queue=4)
        worker.start()
        start = time.perf_counter()
        dropped = sum(worker.submit(InferenceJob(i, paired(i))) for i in range(200))
        submit_s = time.perf_counter() - start
        await asyncio.wait_for(worker.wait_below(1), 20)
        await worker.stop()
        return dropped, submit_s

    dropped, submit_s = asyncio.run(body())
    assert dropped > 0
    assert submit_s < 0.5  # 200 submits never waited for the model
    assert len(results) == 200 - dropped
    seqs = [r.job.seq for r in results]
    assert seqs == sorted(seqs)
    assert seqs[-1] == 199  # the newest frames survive, the oldest were dropped
    delivered = set(seqs)
    after_drop = [r for r in results if r.job.seq > 0 and r.job.seq - 1 not in delivered]
    assert after_drop
    assert all(r.restarted for r in after_drop)  # the cache would have missed a frame


def test_a_frame_the_model_rejects_is_reported_and_the_worker_goes_on(
    runtime: ScottiRuntime,
) -> None:
    results: list[InferenceResult] = []
    bad = PairedFrame(np.zeros((3, 3), dtype=np.uint16), (0, 0), (0, 0), 0)

    async def body() -> None:
        worker = InferenceWorker(Window(runtime), results.append)
        worker.start()
        worker.submit(InferenceJob(0, bad))
        worker.submit(InferenceJob(1, paired(1)))
        await asyncio.wait_for(worker.wait_below(1), 10)
        await worker.stop()

    asyncio.run(body())
    assert results[0].output is None
    assert results[0].error is not None
    assert "must be" in results[0].error
    assert results[1].output is not None


def test_repetitions_count_wraps_of_progress_with_hysteresis() -> None:
    counter = RepetitionCounter()
    rng = np.random.default_rng(0)
    reps = []
    for i in range(16 * 5):  # five repetitions of 1 s each
        progress = (i % 16) / 15 + float(rng.normal(0, 0.03))
        reps.append(counter.update(2, progress))
    assert reps[0] == 0
    assert reps[-1] == 4  # four wraps from high to low completed
    assert counter.update(2, float("nan")) == 4
    # One frame of another action is a flicker; four frames are a new action.
    assert counter.update(5, 0.1) == 4
    assert counter.update(2, 0.5) == 4
    for _ in range(4):
        got = counter.update(6, 0.1)
    assert got == 0
    assert counter.action == 6


def test_standing_counts_nothing_and_a_short_flicker_to_it_does_not_reset() -> None:
    counter = RepetitionCounter()
    squat, standing = ACTIONS.index("squat"), STANDING
    wrap = [0.2, 0.5, 0.9, 0.1]  # one completed repetition per pass
    reps = [counter.update(squat, p) for p in wrap * 3]
    assert reps[-1] == 3
    # Two frames of standing at the top of a squat: a flicker, the count holds.
    assert counter.update(standing, 0.05) == 3
    assert counter.update(standing, 0.9) == 3
    assert counter.update(squat, 0.5) == 3
    # Standing held: the count is -1 (none), whatever the progress head says.
    got = [counter.update(standing, p) for p in wrap * 2]
    assert got[:3] == [3, 3, 3]
    assert got[3:] == [-1] * (len(got) - 3)
    assert counter.action == standing
    # The same action back after a short standing: a pause in the set, the count goes on.
    for _ in range(4):
        got_back = counter.update(squat, 0.5)
    assert got_back == 3
    assert [counter.update(squat, p) for p in wrap][-1] == 4


def test_a_set_resumes_after_a_pause_and_starts_over_after_a_long_stand() -> None:
    squat, lunge = ACTIONS.index("squat"), ACTIONS.index("lunge")
    wrap = [0.2, 0.5, 0.9, 0.1]  # one completed repetition per pass

    def after_standing(frames: int, then: int) -> int:
        counter = RepetitionCounter(resume_frames=20)
        for p in wrap * 2:
            counter.update(squat, p)
        standing = [counter.update(STANDING, 0.0) for _ in range(frames)]
        assert standing[-1] == -1
        # The first pass confirms the action (its progress unread), the second counts.
        return [counter.update(then, p) for p in wrap * 2][-1]

    assert after_standing(20, squat) == 3  # within resume_frames: the set goes on
    assert after_standing(21, squat) == 1  # beyond it: a new set counts from 0
    assert after_standing(10, lunge) == 1  # another exercise counts from 0
    # A standing entered from another exercise resumes nothing of the one before it.
    counter = RepetitionCounter(resume_frames=20)
    for action in (squat, lunge):
        for p in wrap * 2:
            counter.update(action, p)
    for _ in range(6):
        counter.update(STANDING, 0.0)
    assert [counter.update(squat, p) for p in wrap * 2][-1] == 1


def test_a_repetition_whose_progress_turns_down_before_the_top_still_counts() -> None:
    # A step-up as a model unsure of the arrival predicts it: rest ~0, up to ~0.5 on
    # the step, ~0.6 at most on the way down, then back to ~0 on the floor.
    counter = RepetitionCounter()
    one = [0.02] * 10 + [0.1, 0.2, 0.3, 0.4, 0.5] + [0.5] * 10 + [0.58, 0.6, 0.45, 0.25, 0.05]
    got = [counter.update(ACTIONS.index("step_up"), p) for p in one * 3]
    assert got[-1] == 3


def test_noise_around_one_level_does_not_count() -> None:
    counter = RepetitionCounter()
    values = [0.5 + 0.15 * math.sin(i) for i in range(200)]
    assert max(counter.update(0, v) for v in values) == 0


def test_latency_percentiles_come_from_the_last_values_only() -> None:
    ring = LatencyRing(size=100)
    for v in range(1000):
        ring.add(float(v))
    summary = ring.summary()
    assert summary["n"] == 100
    assert summary["max"] == 999.0
    assert 948 <= summary["p50"] <= 951
    assert summary["p99"] >= 997
    assert LatencyRing().summary()["n"] == 0


def test_counters_snapshot_is_plain_json() -> None:
    counters = Counters()
    counters.inference_ms.add(1.5)
    counters.observe_queue(3)
    counters.observe_queue(1)
    snap = json.loads(json.dumps(counters.snapshot()))
    assert snap["queue_depth"] == 1
    assert snap["queue_depth_max"] == 3
    assert snap["latency_ms"]["inference"]["p50"] == 1.5
    assert snap["frames_in"] == {"left": 0, "right": 0}
    assert snap["uptime_s"] >= 0


def test_one_engine_runs_ready_devices_in_one_call_with_the_results_of_separate_windows(
    runtime: ScottiRuntime,
) -> None:
    devices = 4
    frames_each = Window(runtime).needed + 2
    results: dict[int, list[InferenceResult]] = {d: [] for d in range(devices)}

    async def body() -> tuple[int, int]:
        engine = InferenceEngine(batch=True)
        lanes = [
            engine.lane(Window(runtime), results[d].append, max_queue=64) for d in range(devices)
        ]
        for lane in lanes:
            lane.start()
        # Everything queued before the engine runs: each turn finds all four ready.
        for i in range(frames_each):
            for d, lane in enumerate(lanes):
                lane.submit(InferenceJob(i, paired(100 * d + i)))
        engine.start()
        for lane in lanes:
            await asyncio.wait_for(lane.wait_below(1), 20)
        for lane in lanes:
            await lane.stop()
        await engine.stop()
        return engine.turns, engine.frames

    turns, ran = asyncio.run(body())
    assert ran == devices * frames_each
    assert turns == frames_each  # one model call per turn, four devices in each
    assert all(r.batch_size == devices for rs in results.values() for r in rs)
    for d in range(devices):  # the same as that device's frames through a window of its own
        alone = Window(runtime)
        expected = [alone.push(paired(100 * d + i).counts) for i in range(frames_each)]
        got = [r.output for r in results[d]]
        assert [r.job.seq for r in results[d]] == list(range(frames_each))
        for want, have in zip(expected, got, strict=True):
            assert have is not None
            assert want.warming == have.warming
            if want.result is not None and have.result is not None:
                np.testing.assert_allclose(have.result.pose, want.result.pose, atol=1e-5)


def test_a_bad_frame_in_a_batch_fails_only_its_own_device(runtime: ScottiRuntime) -> None:
    good: list[InferenceResult] = []
    bad: list[InferenceResult] = []
    broken = PairedFrame(np.zeros((3, 3), dtype=np.uint16), (0, 0), (0, 0), 0)

    async def body() -> None:
        engine = InferenceEngine(batch=True)
        ok_lane = engine.lane(Window(runtime), good.append)
        bad_lane = engine.lane(Window(runtime), bad.append)
        ok_lane.start()
        bad_lane.start()
        ok_lane.submit(InferenceJob(0, paired(0)))
        bad_lane.submit(InferenceJob(0, broken))
        bad_lane.submit(InferenceJob(1, paired(1)))
        engine.start()
        await asyncio.wait_for(ok_lane.wait_below(1), 10)
        await asyncio.wait_for(bad_lane.wait_below(1), 10)
        await engine.stop()

    asyncio.run(body())
    assert good[0].output is not None
    assert good[0].error is None
    assert bad[0].output is None
    assert bad[0].error is not None
    assert "must be" in bad[0].error
    assert bad[1].output is not None  # and that device goes on


@pytest.mark.parametrize(
    ("batch", "max_batch", "sizes"),
    [(False, 8, [1, 1, 1, 1, 1]), (True, 2, [1, 2, 2, 2, 2]), (True, 8, [5] * 5)],
)
def test_frames_per_model_call_follow_batch_and_max_batch(
    runtime: ScottiRuntime, batch: bool, max_batch: int, sizes: list[int]
) -> None:
    got: list[InferenceResult] = []

    async def body() -> int:
        engine = InferenceEngine(batch=batch, max_batch=max_batch)
        lanes = [engine.lane(Window(runtime), got.append) for _ in range(5)]
        for i, lane in enumerate(lanes):
            lane.start()
            lane.submit(InferenceJob(0, paired(i)))
        engine.start()  # all five ready at its first turn
        for lane in lanes:
            await asyncio.wait_for(lane.wait_below(1), 10)
        await engine.stop()
        return engine.turns

    assert asyncio.run(body()) == 1
    assert sorted(r.batch_size for r in got) == sizes


def test_gather_waits_for_a_due_device_and_runs_both_in_one_call(runtime: ScottiRuntime) -> None:
    """inference.gather_ms: a frame waits for another device's frame that is due (its
    last came about a frame period ago), and the two go in one model call."""
    got: dict[str, list[InferenceResult]] = {"a": [], "b": []}
    delivered_at: dict[str, float] = {}

    async def body() -> InferenceEngine:
        # Under a frame period (a device's own next frame is not due within it); b comes
        # 15 ms after a: 40 ms of margin for a slow host.
        engine = InferenceEngine(batch=True, gather_ms=55)

        def on(name: str) -> Any:
            def take(r: InferenceResult) -> None:
                got[name].append(r)
                delivered_at[name] = time.monotonic()

            return take

        a, b = engine.lane(Window(runtime), on("a")), engine.lane(Window(runtime), on("b"))
        a.start()
        b.start()
        engine.start()
        a.submit(InferenceJob(0, paired(0)))
        b.submit(InferenceJob(0, paired(1)))
        await asyncio.wait_for(a.wait_below(1), 10)
        await asyncio.wait_for(b.wait_below(1), 10)
        await asyncio.sleep(0.0625)  # both due again now
        a.submit(InferenceJob(1, paired(2)))
        await asyncio.sleep(0.015)  # b's frame comes 15 ms later
        b_sent = time.monotonic()
        b.submit(InferenceJob(1, paired(3)))
        await asyncio.wait_for(a.wait_below(1), 10)
        await asyncio.wait_for(b.wait_below(1), 10)
        assert delivered_at["a"] >= b_sent  # a waited for b
        await engine.stop()
        return engine

    engine = asyncio.run(body())
    assert got["a"][-1].batch_size == 2
    assert got["b"][-1].batch_size == 2
    assert engine.gathered >= 1
    stats = engine.stats()
    assert stats["frames"] == 4
    # stats() rounds to 2 decimals: 3 calls (a busy host split the first round) say 1.33.
    assert stats["frames_per_call"] == pytest.approx(4 / stats["model_calls"], abs=0.005)


def test_gather_never_waits_for_a_silent_device_or_for_one_alone(runtime: ScottiRuntime) -> None:
    got: list[InferenceResult] = []

    async def body() -> InferenceEngine:
        engine = InferenceEngine(batch=True, gather_ms=55)
        a, b = engine.lane(Window(runtime), got.append), engine.lane(Window(runtime), got.append)
        a.start()
        b.start()
        engine.start()
        b.submit(InferenceJob(0, paired(1)))  # then silent: unplugged
        await asyncio.wait_for(b.wait_below(1), 10)
        await asyncio.sleep(0.0625 + 0.25)  # its next frame is long overdue
        for i in range(3):  # a alone, every frame period
            a.submit(InferenceJob(i, paired(10 + i)))
            await asyncio.wait_for(a.wait_below(1), 10)
            await asyncio.sleep(0.0625)
        await engine.stop()
        return engine

    engine = asyncio.run(body())
    assert engine.gathered == 0
    assert [r.batch_size for r in got] == [1, 1, 1, 1]
