"""Repetitions counted the daemon's way (daemon/inference/published.py): the rule the
pipeline publishes by, and experiments/demo_progress.py's counts through it."""

from __future__ import annotations

import asyncio
import math
import sys
from collections.abc import Iterable
from pathlib import Path

import numpy as np
from scotti.daemon.frames.pipeline import Pipeline, Prediction
from scotti.daemon.inference.published import Published, publish
from scotti.daemon.inference.repetitions import RepetitionCounter
from scotti.daemon.input.sources import ReplaySource
from scotti.daemon.service.counters import Counters
from scotti.evaluation.replay import replay_session
from scotti.firmware_protocol.framing import encode_packet
from scotti.firmware_protocol.packets import Foot
from scotti.firmware_protocol.session import SessionHeader, SessionWriter
from scotti.models.contract import ACTIONS, FRAME_COLS, FRAME_ROWS, NO_ACTION, STANDING
from scotti.models.input_checks import UNLOADED_FRAMES
from scotti.models.ood import UNFAMILIAR
from scotti.models.runtime import ScottiRuntime

from tests.support.sessions import PERIOD_NS, PERIOD_US, frame_packets, synthetic_counts

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments"))
from demo_progress import completed, published, streams

SQUAT = ACTIONS.index("squat")
ONE_REP = [0.05, 0.2, 0.4, 0.6, 0.8, 0.9, 0.5, 0.2, 0.05]  # up through 0.55, down through 0.3
TOP = [i for i, p in enumerate(ONE_REP) if p >= 0.55]


def run(steps: Iterable[tuple[int, float, tuple[str, ...]]]) -> list[Published]:
    counter = RepetitionCounter()
    return [publish(a, p, flags, counter) for a, p, flags in steps]


def test_a_withheld_rep_top_is_not_counted_the_daemon_way_but_would_be_ignoring_flags() -> None:
    """Three squats; the top of the second is unfamiliar. The daemon publishes nothing
    for those frames and its counter never saw the second squat armed: 2, not 3."""
    steps = [
        (SQUAT, p, (UNFAMILIAR,) if rep == 1 and i in TOP else ())
        for rep in range(3)
        for i, p in enumerate(ONE_REP)
    ]
    daemon = run(steps)
    ignoring = run([(a, p, ()) for a, p, _ in steps])
    assert completed(daemon) == {SQUAT: 2}
    assert completed(ignoring) == {SQUAT: 3}
    flagged = [p for p in daemon if p.withheld is not None]
    assert len(flagged) == len(TOP)
    assert all(p.withheld == UNFAMILIAR for p in flagged)
    assert all((p.action, p.repetition) == (NO_ACTION, -1) for p in flagged)
    assert all(math.isnan(p.progress) for p in flagged)


def test_a_withheld_frame_neither_counts_nor_forgets() -> None:
    """The fall after an unflagged top is flagged at its bottom only: the count waits
    for the next published frame below 0.3, and the top is not forgotten."""
    down = ONE_REP.index(0.05, 1)
    steps = [(SQUAT, p, ("unloaded",) if i == down else ()) for i, p in enumerate(ONE_REP)]
    steps.append((SQUAT, 0.1, ()))
    out = run(steps)
    assert out[down].withheld == "unloaded"
    assert [p.repetition for p in out[-2:]] == [-1, 1]
    # Standing publishes no progress and no count, flagged or not.
    counter = RepetitionCounter()
    assert publish(STANDING, 0.7, (), counter).repetition == -1
    assert math.isnan(publish(STANDING, 0.7, (), counter).progress)


def test_a_set_split_by_standing_counts_each_repetition_once() -> None:
    """Two squats, a pause long enough to read standing (8 frames), two more: the counter
    goes on at 2 and the count of completions is 4, not 2 + 4 (a resumed count is no
    completion) nor 2 (the count starting over)."""
    squats = [(SQUAT, p, ()) for _ in range(2) for p in ONE_REP]
    pause = [(STANDING, 0.0, ())] * 8
    out = run(squats + pause + squats)
    assert [p.repetition for p in out[len(squats) : len(squats) + len(pause)]][-1] == -1
    assert out[-1].repetition == 4
    assert completed(out) == {SQUAT: 4}
    # After a stand longer than a pause the next set starts over, and counts its own.
    long_stand = [(STANDING, 0.0, ())] * (RepetitionCounter().resume_frames + 8)
    out = run(squats + long_stand + squats)
    assert out[-1].repetition == 2
    assert completed(out) == {SQUAT: 4}


# --- the real pipeline against the replay counted through the same rule ------------

EMPTY_FROM, EMPTY_TO = 120, 150  # nobody on the insoles: unloaded once 16 frames in
GAP_FROM, GAP_TO = 200, 230  # no frames for 30 (> 16): the window restarts
FRAMES = 320


def counts_of(foot: Foot, seq: int, i: int) -> np.ndarray:
    """A plausible map whose load swells and ebbs (so the progress head's output moves)."""
    if EMPTY_FROM <= i < EMPTY_TO:
        return np.zeros((FRAME_ROWS, FRAME_COLS), np.uint16)
    scale = 0.3 + 0.35 * (1 + math.sin(2 * math.pi * i / 24))
    return (synthetic_counts(foot, seq) * scale).astype(np.uint16)


def write_session(path: Path) -> Path:
    """Both feet at 16 Hz, frames GAP_FROM..GAP_TO never sent (their seqs skipped)."""
    header = SessionHeader(source="simulated", device="synthetic", scene={"name": "gap"})
    with SessionWriter(path, header) as writer:
        for i in range(FRAMES):
            if GAP_FROM <= i < GAP_TO:
                continue
            t = 1_000_000_000 + i * PERIOD_NS
            for foot in (Foot.LEFT, Foot.RIGHT):
                clock = 1_000_000 + i * PERIOD_US + 7_000 * int(foot)
                for packet in frame_packets(foot, i, clock, counts_of(foot, i, i)):
                    writer.write_packet(t, encode_packet(packet))
                    t += 1_000_000
    return path


def pipeline_predictions(path: Path, model: Path, high: float, low: float) -> list[Prediction]:
    """What ``scotti-daemon --replay`` publishes, its counter at these thresholds."""
    out: list[Prediction] = []

    async def go() -> None:
        pipeline = Pipeline(ReplaySource(path, speed="max"), ScottiRuntime(model), Counters())
        pipeline.repetitions = RepetitionCounter(high, low)
        await pipeline.run(out.append, lambda _: None, asyncio.Event())

    asyncio.run(go())
    return out


def test_the_replay_counted_the_daemon_way_is_what_the_pipeline_publishes(
    tmp_path: Path, tiny_model_path: Path
) -> None:
    """The tiny model's progress moves by a thousandth, so the counter's thresholds sit
    inside that range (the rule, not the thresholds, is under test). An unloaded stretch
    withholds predictions mid-count and a gap restarts the window: the daemon's pipeline
    and demo_progress's counting agree on every prediction."""
    path = write_session(tmp_path / "gap.scotti")
    made = replay_session(path, ScottiRuntime(tiny_model_path)).made
    progress = np.array([m.progress for m in made if not m.flags])
    high, low = (float(q) for q in np.quantile(progress, [0.7, 0.3]))
    daemon = pipeline_predictions(path, tiny_model_path, high, low)
    ours = published(made, high=high, low=low)

    assert len(streams(made)) == 2  # the gap
    assert len(ours) == len(daemon) == len(made)
    for m, p, d in zip(made, ours, daemon, strict=True):
        assert (m.ext - 1) % 65536 == d.left_seq
        assert (p.action, p.repetition, p.withheld) == (d.action, d.repetition, d.withheld)
        assert p.progress == d.progress or (math.isnan(p.progress) and math.isnan(d.progress))
    withheld = [d.left_seq for d in daemon if d.withheld is not None]
    assert withheld == list(range(EMPTY_FROM + UNLOADED_FRAMES - 1, EMPTY_TO))
    counts = completed(ours)
    assert sum(counts.values()) > 0  # the comparison above saw repetitions counted
    # Restarting the counter matters here: one stream through one counter would differ.
    one = RepetitionCounter(high, low)
    joined = [publish(int(np.argmax(m.probs)), m.progress, m.flags, one).repetition for m in made]
    assert joined != [d.repetition for d in daemon]
