"""What training reads is what the daemon serves: the frames ``export.data`` lays out for
training equal, byte for byte, the frames the daemon's own pipeline hands its window
when it replays the same session file.

The daemon is run for real (``Pipeline`` on a ``ReplaySource``, the tiny exported model);
each of its predictions carries the pair its window ended at (``Prediction.counts``)
and that pair's number since the start (``Prediction.seq``), which is the training
slot. The sessions lose rows, silence a foot, wrap their seqs, restart their boards,
go quiet longer than the restart gap, and one is a simulated scene with transport
effects. ``export.data`` needs no torch: nothing here is skipped without it.
"""

from __future__ import annotations

import asyncio
from pathlib import Path

import numpy as np
import pytest
from scotti.cli.main import main
from scotti.daemon.frames.pipeline import Pipeline, Prediction
from scotti.daemon.input.sources import ReplaySource
from scotti.daemon.service.counters import Counters
from scotti.export.data import SessionArrays, decode_session
from scotti.firmware_protocol.pairing import HOLD_FRAMES, RESTART_GAP_FRAMES
from scotti.models.runtime import ScottiRuntime

from tests.support.export_sessions import write_session

SIM_SCENE = """
name = "parity"
seed = 11
[subject]
height_m = 1.7
mass_kg = 65.0
style_seed = 1
[[script]]
action = "squat"
reps = 2
stand_s = 0.5
[[effects]]
name = "packet_loss"
p_good_to_bad = 0.05
p_bad_to_good = 0.3
loss_bad = 0.8
[[effects]]
name = "foot_offset"
foot = "right"
offset_ms = 20.0
[[effects]]
name = "jitter"
std_ms = 3.0
[[effects]]
name = "unplug"
start_s = 3.0
duration_s = 1.5
"""


@pytest.fixture(scope="module")
def runtime(tiny_model_path: Path) -> ScottiRuntime:
    return ScottiRuntime(tiny_model_path)


def served(path: Path, runtime: ScottiRuntime) -> tuple[list[Prediction], Counters]:
    """The daemon replaying ``path`` as fast as it can (no MQTT): every prediction."""
    out: list[Prediction] = []
    counters = Counters()

    async def go() -> None:
        pipeline = Pipeline(ReplaySource(path, speed="max"), runtime, counters)
        await pipeline.run(out.append, lambda _: None, asyncio.Event())

    asyncio.run(go())
    return out, counters


def assert_parity(path: Path, runtime: ScottiRuntime) -> SessionArrays:
    trained = decode_session(path)
    predictions, counters = served(path, runtime)
    # Every pair the daemon made is a training slot, in the same order.
    assert len(trained) == counters.pairing.pairs_out
    # The daemon predicts once its window holds T frames since the last restart.
    t = runtime.window
    starts = np.flatnonzero(np.diff(trained.segment, prepend=-1))
    run_pos = np.arange(len(trained)) - starts[trained.segment]
    assert [p.seq for p in predictions] == np.flatnonzero(run_pos >= t - 1).tolist()
    for p in predictions:
        assert p.counts.tobytes() == trained.frames[p.seq].tobytes(), f"slot {p.seq}"
        assert p.left_seq == trained.seq[p.seq] % 65536
    # What the daemon flagged as zero-filled is what training leaves out.
    filled = {p.seq for p in predictions if {"left_filled", "right_filled"} & set(p.flags)}
    assert filled == {p.seq for p in predictions if not trained.frame_ok[p.seq]}
    return trained


def test_lost_rows_a_silent_foot_and_a_wrap(tmp_path: Path, runtime: ScottiRuntime) -> None:
    silent = range(70, 70 + HOLD_FRAMES + 5)
    path = write_session(
        tmp_path / "lossy.scotti",
        140,
        first_seq=65536 - 50,
        drop_foot=[(20, 1), (21, 0), *((k, 1) for k in silent)],
        drop_rows=[(30, 0, 0), (31, 1, 3), (100, 0, 2)],
        garbage_every=13,
    )
    trained = assert_parity(path, runtime)
    assert trained.counters["zero_filled"] > 0  # the silence outlasted the hold
    assert trained.repaired.any()
    assert not trained.valid.all()
    assert (np.diff(trained.seq) == 1).all()  # across 65535 -> 0


def test_boards_that_restart_and_an_outage(tmp_path: Path, runtime: ScottiRuntime) -> None:
    path = write_session(tmp_path / "restart.scotti", 150, first_seq=500, restart=(60, 0))
    trained = assert_parity(path, runtime)
    assert trained.counters["resyncs"] == 2  # both boards counted again from 0
    assert trained.has_label.sum() == 150  # every label found its pair
    gap = write_session(tmp_path / "gap.scotti", 120, seq_jump=(50, RESTART_GAP_FRAMES + 10))
    trained = assert_parity(gap, runtime)
    assert trained.segment.max() == 1  # the window started over after the outage


def test_a_simulated_scene_with_transport_effects(tmp_path: Path, runtime: ScottiRuntime) -> None:
    scene = tmp_path / "parity.toml"
    scene.write_text(SIM_SCENE)
    path = tmp_path / "parity.scotti"
    assert main(["sim", str(scene), "-o", str(path)]) == 0
    trained = assert_parity(path, runtime)
    assert trained.counters["incomplete_frames"] > 0  # blocks were lost
    assert trained.segment.max() >= 1  # the unplug restarted the window
