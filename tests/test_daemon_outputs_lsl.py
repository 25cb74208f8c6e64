"""``--lsl``: pylsl inlets on this machine find the daemon's outlets and read
pose, action probabilities, progress and pressure, stamped with the frame's time."""

from __future__ import annotations

import asyncio
import time
import uuid
from pathlib import Path

import numpy as np
import pytest
from scotti.daemon.frames.pipeline import Prediction
from scotti.firmware_protocol.packets import Foot
from scotti.models.contract import ACTIONS, FRAME_COLS, FRAME_ROWS, KEYPOINTS, NUM_ACTIONS

from tests.support.outputs import lsl_on_this_host, predictions
from tests.support.sessions import synthetic_counts, write_synthetic_session

lsl_on_this_host()
pylsl = pytest.importorskip("pylsl")

TIMEOUT_S = 10.0


@pytest.fixture(scope="module")
def preds(tmp_path_factory: pytest.TempPathFactory, tiny_model_path: Path) -> list[Prediction]:
    session = write_synthetic_session(tmp_path_factory.mktemp("lsl") / "s.scotti", frames=48)
    return predictions(session.path, tiny_model_path)


def test_lsl_clock_is_the_hosts_monotonic_clock() -> None:
    # The outlets stamp samples with time.monotonic_ns(); that is LSL time only if
    # liblsl's local_clock reads the same steady clock.
    assert abs(pylsl.local_clock() - time.monotonic()) < 0.05


def test_inlets_read_what_the_outlets_send(preds: list[Prediction]) -> None:
    from scotti.daemon.outputs.lsl import LslOutput

    device = f"test-{uuid.uuid4().hex[:8]}"  # never another run's outlets
    output = LslOutput([device])
    inlets = {}
    for what in ("pose", "action", "progress", "pressure"):
        (info,) = pylsl.resolve_byprop("source_id", f"scotti/{device}/{what}", 1, TIMEOUT_S)
        assert info.name() == f"{device} {what}"  # a lone device's names, as always
        inlets[what] = pylsl.StreamInlet(info, max_buflen=60)
        inlets[what].open_stream(timeout=TIMEOUT_S)
    pose_info = inlets["pose"].info(timeout=TIMEOUT_S)
    assert pose_info.channel_count() == 3 * len(KEYPOINTS) == 57
    assert pose_info.get_channel_labels()[:3] == ["nose_x", "nose_y", "nose_z"]
    assert inlets["action"].info().get_channel_labels() == list(ACTIONS)
    assert inlets["pressure"].info().channel_count() == 2 * FRAME_ROWS * FRAME_COLS
    time.sleep(0.2)  # the inlets' connections settle before the first sample
    sent = preds[:10]
    for p in sent:
        output.prediction(device, p, 1.0)
    got = {what: inlet.pull_chunk(timeout=TIMEOUT_S, max_samples=len(sent))
           for what, inlet in inlets.items()}  # fmt: skip
    for what, (samples, stamps) in got.items():
        assert len(samples) == len(sent), what
        np.testing.assert_allclose(stamps, [p.last_byte_mono_ns / 1e9 for p in sent], atol=1e-6)
    for p, pose, probs, prog, pressure in zip(
        sent, *(got[w][0] for w in ("pose", "action", "progress", "pressure")), strict=True
    ):
        np.testing.assert_allclose(np.reshape(pose, (-1, 3)), p.pose, atol=1e-6)
        assert len(probs) == NUM_ACTIONS
        np.testing.assert_allclose(probs, p.action_probs, atol=1e-6)
        assert prog[1] == p.repetition
        left = np.reshape(pressure[: FRAME_ROWS * FRAME_COLS], (FRAME_ROWS, FRAME_COLS))
        right = np.reshape(pressure[FRAME_ROWS * FRAME_COLS :], (FRAME_ROWS, FRAME_COLS))
        np.testing.assert_array_equal(left, synthetic_counts(Foot.LEFT, p.left_seq))
        np.testing.assert_array_equal(right, synthetic_counts(Foot.RIGHT, p.right_seq))
    asyncio.run(output.close())


def test_one_outlet_set_per_device_named_after_it(preds: list[Prediction]) -> None:
    from scotti.daemon.outputs.lsl import LslOutput

    run = uuid.uuid4().hex[:8]
    devices = (f"a-{run}", f"b-{run}")
    output = LslOutput(devices)
    inlets = {}
    for device in devices:
        (info,) = pylsl.resolve_byprop("source_id", f"scotti/{device}/action", 1, TIMEOUT_S)
        assert info.name() == f"{device} action"  # what LabRecorder lists
        inlets[device] = pylsl.StreamInlet(info, max_buflen=60)
        inlets[device].open_stream(timeout=TIMEOUT_S)
    # Every device has all four streams, and only these eight carry this run's ids.
    found = [s for s in pylsl.resolve_streams(1.0) if run in s.source_id()]
    assert sorted(s.source_id() for s in found) == sorted(
        f"scotti/{d}/{w}" for d in devices for w in ("pose", "action", "progress", "pressure")
    )
    time.sleep(0.2)  # the inlets' connections settle before the first sample
    a, b = devices
    sent = {a: preds[:3], b: preds[3:6]}
    for to_a, to_b in zip(sent[a], sent[b], strict=True):  # interleaved, as the devices run
        output.prediction(a, to_a, 1.0)
        output.prediction(b, to_b, 1.0)
    for p in preds[6:9]:  # then b falls silent: a's samples go on alone
        output.prediction(a, p, 1.0)
    sent[a] = sent[a] + preds[6:9]
    for device, inlet in inlets.items():
        samples: list[list[float]] = []
        stamps: list[float] = []
        while len(samples) < len(sent[device]):
            more, at = inlet.pull_chunk(timeout=TIMEOUT_S, max_samples=len(sent[device]))
            assert more, f"{device}: {len(samples)} of {len(sent[device])} samples"
            samples, stamps = samples + more, stamps + at
        np.testing.assert_allclose(stamps, [p.last_byte_mono_ns / 1e9 for p in sent[device]])
        np.testing.assert_allclose(samples, [p.action_probs for p in sent[device]], atol=1e-6)
    assert inlets[b].pull_chunk(timeout=0.5)[0] == []  # nothing of a's in b's stream
    asyncio.run(output.close())
