"""The bench's parts without a daemon: its boards' frames, its pose reader, its profile."""

from __future__ import annotations

import os
import select
import time
from pathlib import Path

import numpy as np
import pytest
from scotti.daemon.tools.bench_boards import BoardPlayer, person_counts
from scotti.daemon.tools.bench_profile import EVENT_LOOP, OTHER, part_of_stack, shares
from scotti.daemon.tools.bench_subscriber import read_pose
from scotti.firmware_protocol.framing import StreamDecoder
from scotti.firmware_protocol.packets import FrameRows
from scotti.models.input_checks import frame_stats, window_flags


def test_the_simulated_people_look_like_insole_frames_to_the_input_checks() -> None:
    counts = person_counts(1)  # (N, 2, 32, 22): left and right
    frames = np.concatenate([counts[:, 0], counts[:, 1]], axis=2)  # the model's (H, 2W)
    unloaded, out_of_range = window_flags(frame_stats(frames))
    assert len(frames) > 160  # seconds of movement, not a still frame
    assert out_of_range.mean() < 0.01  # random maps: every window
    assert not unloaded.any()  # someone stands on them throughout
    assert not np.array_equal(person_counts(2)[:50], counts[:50])  # people differ


def _read(fds: list[int], seconds: float) -> list[list[FrameRows]]:
    """What each reader gets in ``seconds``, decoded."""
    decoders = {fd: StreamDecoder() for fd in fds}
    items: dict[int, list[object]] = {fd: [] for fd in fds}
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        ready, _, _ = select.select(fds, [], [], 0.05)
        for fd in ready:
            items[fd] += decoders[fd].feed(os.read(fd, 65536))
    for got in items.values():  # whole, good packets only
        assert all(isinstance(i, FrameRows) for i in got), got
    return [items[fd] for fd in fds]  # type: ignore[misc]


def test_boards_play_whole_frames_at_16_hz_with_numbers_going_on_over_the_loop(
    tmp_path: Path,
) -> None:
    short = person_counts(0)[:20]  # a 20-frame loop: the seam comes within the test
    links = [tmp_path / "tty0", tmp_path / "tty1"]
    player = BoardPlayer(links, [short])
    readers = [os.open(link, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY) for link in links]
    player.start()
    try:
        first, second = _read(readers, 2.0)
    finally:
        player.stop()
        for fd in readers:
            os.close(fd)
    left = [p for p in first if p.foot == 0]
    frames = sorted({p.seq for p in left})
    assert 22 <= len(frames) <= 34  # ~1.9 s at 16 Hz, past the 20-frame loop
    assert frames == list(range(frames[0], frames[0] + len(frames)))  # no jump at the seam
    assert {p.row_start for p in left} == {0, 8, 16, 24}  # 8-row packets
    assert all(len([p for p in left if p.seq == s]) == 4 for s in frames[:-1])
    # Board 1 plays the same person from another phase: its numbers and frames differ.
    assert second
    assert second[0].seq != first[0].seq
    assert player.dropped == 0


@pytest.mark.parametrize(
    "payload",
    [
        b'{"seq":3,"predicted_for_mono_ns":1062500000,"latency_ms":1.25,'
        b'"flags":["left_filled","unfamiliar"],"keypoints":[[0,0,0]]}',
        b'{"latency_ms": 1.25, "predicted_for_mono_ns": 1062500000, '
        b'"flags": ["unfamiliar", "rows_missing"]}',
        b'{"predicted_for_mono_ns": 1062500000, "flags": ["unfamiliar"], "latency_ms": 125e-2}',
    ],
)
def test_the_pose_reader_finds_the_three_fields_in_any_layout(payload: bytes) -> None:
    assert read_pose(payload) == (1_062_500_000, 1.25, 0b100)


def test_the_pose_reader_sees_no_flag_in_an_empty_list() -> None:
    payload = b'{"predicted_for_mono_ns":5,"latency_ms":0.5,"flags":[],"keypoints":[]}'
    assert read_pose(payload) == (5, 0.5, 0)


RAW = """\
process 1:"python";main (scotti/daemon/service/main.py:9);run (asyncio/runners.py:1);BaseEventLoop._run_once (asyncio/base_events.py:1);Handle._run (asyncio/events.py:8);Pipeline._consume (daemon/frames/pipeline.py:2);FramePath.feed (firmware_protocol/frame_path.py:5) 30
process 1:"python";main (scotti/daemon/service/main.py:9);run (asyncio/runners.py:1);BaseEventLoop._run_once (asyncio/base_events.py:1907) 10
process 1:"python";main (scotti/daemon/service/main.py:9);BaseEventLoop._run_once (asyncio/base_events.py:1);EpollSelector.select (selectors.py:468) 500
Thread.run (threading.py:982);InferenceEngine._loop (daemon/inference/engine.py:200);run_steps (models/runtime.py:260);Session.run (onnxruntime/capi/onnxruntime_inference_collection.py:406) 40
Thread.run (threading.py:982);InferenceEngine._loop (daemon/inference/engine.py:200);stack (numpy/_core/shape_base.py:1) 10
Thread.run (threading.py:982);_worker (concurrent/futures/thread.py:81) 300
Thread.run (threading.py:982);mystery (elsewhere.py:1) 10
"""  # noqa: E501


def test_profile_shares_leave_waits_out_and_go_by_the_innermost_part() -> None:
    total, waits, parts, top = shares(RAW)
    assert (total, waits) == (100, 800)
    assert parts["frame path (decode, assemble, pair)"] == pytest.approx(30.0)
    assert parts["model (Session.run)"] == pytest.approx(40.0)
    assert parts["inference thread Python"] == pytest.approx(10.0)  # numpy, called by it
    assert parts[EVENT_LOOP] == pytest.approx(10.0)  # the loop's own, not the service's
    assert parts[OTHER] == pytest.approx(10.0)
    assert sum(parts.values()) == pytest.approx(100.0)
    assert top[0] == (
        "Session.run (onnxruntime/capi/onnxruntime_inference_collection.py:406)",
        40.0,
    )


def test_a_stack_of_paho_under_the_publisher_counts_for_the_publisher() -> None:
    stack = [
        "main (daemon/service/main.py:1)",
        "Handle._run (asyncio/events.py:8)",
        "Publisher._send (daemon/mqtt/publisher.py:3)",
        "Client._sock_send (paho/mqtt/client.py:1)",
    ]
    assert part_of_stack(stack) == "publisher (payloads, paho)"
