"""Streaming: frames one by one through the step graph equal the window graph."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest
from scotti.models import contract as c
from scotti.models.errors import ModelError, ModelInputError
from scotti.models.runtime import ScottiRuntime, load_pair
from scotti.models.streaming import EmbeddingCache, StreamingWindow, push_many

FRAME = (c.FRAME_ROWS, 2 * c.FRAME_COLS)
TOL = 1e-4


def frames(n: int, seed: int = 0) -> npt.NDArray[np.float32]:
    rng = np.random.default_rng(seed)
    return rng.gamma(0.6, 600.0, (n, *FRAME)).clip(0, c.MAX_COUNT).astype(np.float32)


@pytest.fixture
def pair(tiny_model_path: Path) -> tuple[ScottiRuntime, ScottiRuntime]:
    return load_pair(tiny_model_path)


def test_cache_keeps_the_last_embeddings_in_order_without_reallocating() -> None:
    cache = EmbeddingCache(size=3, dim=2)
    first_view = cache.past()
    np.testing.assert_array_equal(first_view, np.zeros((3, 2)))
    for i in range(1, 8):
        cache.push([i, -i])
        past = cache.past()
        expected = [[max(j, 0), -max(j, 0)] for j in range(i - 2, i + 1)]
        np.testing.assert_array_equal(past, expected)
        assert past.flags.c_contiguous
        assert np.shares_memory(past, first_view)  # same buffer, never reallocated
    assert cache.count == 3
    with pytest.raises(ValueError, match="read-only"):
        cache.past()[0, 0] = 1.0
    cache.reset()
    assert cache.count == 0
    np.testing.assert_array_equal(cache.past(), np.zeros((3, 2)))
    with pytest.raises(ModelInputError, match=r"embedding must be \(2,\)"):
        cache.push([1.0, 2.0, 3.0])


def test_window_warms_for_t_minus_one_frames(pair: tuple[ScottiRuntime, ScottiRuntime]) -> None:
    window = StreamingWindow(pair[0])
    assert window.needed == c.WINDOW
    x = frames(c.WINDOW)
    warming = [window.warming]
    for i in range(c.WINDOW - 1):
        assert window.push(x[i]) is None
        assert window.frames_in_window == i + 1
        warming.append(window.warming)
    assert all(warming)
    assert window.push(x[-1]) is not None
    assert window.warming is False
    assert window.frames_in_window == c.WINDOW
    assert window.frames_seen == c.WINDOW


def test_streaming_equals_the_window_graph(pair: tuple[ScottiRuntime, ScottiRuntime]) -> None:
    step, whole = pair
    extra = 4
    x = frames(c.WINDOW + extra, seed=1)
    window = StreamingWindow(step)
    streamed = [window.push(f) for f in x][c.WINDOW - 1 :]
    windows = np.stack([x[i : i + c.WINDOW] for i in range(extra + 1)])
    expected = whole.run_windows(windows)
    for k, got in enumerate(streamed):
        assert got is not None
        np.testing.assert_allclose(got.pose, expected.pose[k], atol=TOL)
        np.testing.assert_allclose(got.action_logits, expected.action_logits[k], atol=TOL)
        np.testing.assert_allclose(got.action_probs, expected.action_probs[k], atol=TOL)
        assert got.progress == pytest.approx(float(expected.progress[k]), abs=TOL)
    # Consecutive windows really differ, so the comparison above could fail.
    assert not np.allclose(expected.pose[0], expected.pose[-1], atol=TOL)


def test_reset_starts_a_fresh_window(pair: tuple[ScottiRuntime, ScottiRuntime]) -> None:
    step, whole = pair
    window = StreamingWindow(step)
    for f in frames(25, seed=2):
        window.push(f)
    window.reset()
    assert window.warming
    assert window.frames_seen == 0
    x = frames(c.WINDOW, seed=3)
    results = [window.push(f) for f in x]
    assert all(r is None for r in results[:-1])
    last = results[-1]
    assert last is not None
    expected = whole.run_windows(x[None])
    np.testing.assert_allclose(last.pose, expected.pose[0], atol=TOL)


def test_bad_frame_leaves_the_window_as_it_was(pair: tuple[ScottiRuntime, ScottiRuntime]) -> None:
    window = StreamingWindow(pair[0])
    window.push(frames(1)[0])
    with pytest.raises(ModelInputError, match="frame must be"):
        window.push(np.zeros((c.FRAME_ROWS, c.FRAME_COLS)))
    assert window.frames_seen == 1


def test_streaming_needs_the_step_graph(pair: tuple[ScottiRuntime, ScottiRuntime]) -> None:
    with pytest.raises(ModelError, match="streaming needs the step graph"):
        StreamingWindow(pair[1])


def test_push_many_equals_each_window_pushed_on_its_own(
    pair: tuple[ScottiRuntime, ScottiRuntime],
) -> None:
    step = pair[0]
    streams = [frames(c.WINDOW + 3, seed=10 + k) for k in range(3)]
    alone = [StreamingWindow(step) for _ in streams]
    together = [StreamingWindow(step) for _ in streams]
    together[2].push(streams[2][0])  # windows at different points of their life: not aligned
    alone[2].push(streams[2][0])
    for i in range(1, c.WINDOW + 3):
        expected = [w.push(s[i]) for w, s in zip(alone, streams, strict=True)]
        got = push_many(together, [s[i] for s in streams])
        for want, have in zip(expected, got, strict=True):
            assert (want is None) == (have is None)
            if want is not None and have is not None:
                np.testing.assert_allclose(have.pose, want.pose, atol=1e-5)
                np.testing.assert_allclose(have.action_probs, want.action_probs, atol=1e-5)
                assert have.progress == pytest.approx(want.progress, abs=1e-5)
    assert [w.frames_seen for w in together] == [w.frames_seen for w in alone]


def test_push_many_refuses_a_bad_frame_and_leaves_every_window_as_it_was(
    pair: tuple[ScottiRuntime, ScottiRuntime],
) -> None:
    windows = [StreamingWindow(pair[0]) for _ in range(2)]
    good = frames(1)[0]
    with pytest.raises(ModelInputError, match="frame must be"):
        push_many(windows, [good, np.zeros((3, 3), np.float32)])
    assert [w.frames_seen for w in windows] == [0, 0]
    assert push_many([], []) == []


def test_wire_counts_in_one_array_give_what_float_frames_give_one_by_one(
    pair: tuple[ScottiRuntime, ScottiRuntime],
) -> None:
    """The daemon's batch (uint16 counts stacked in one array) against ``push`` of float
    copies: same predictions, flags and reasons, also where the input checks flag."""
    step = pair[0]
    counts = [frames(c.WINDOW + 30, seed=20 + k).round().astype(np.uint16) for k in range(3)]
    counts[1][c.WINDOW - 5 : c.WINDOW + 25] = 0  # nobody there: unloaded
    counts[2][5:12, 0, 0] = c.MAX_COUNT  # load outside the outline: out_of_range
    alone = [StreamingWindow(step) for _ in counts]
    together = [StreamingWindow(step) for _ in counts]
    flags = set()
    for i in range(c.WINDOW + 30):
        batch = np.stack([s[i] for s in counts])
        got = push_many(together, batch)
        for w, s, have in zip(alone, counts, got, strict=True):
            want = w.push(s[i].astype(np.float32))
            assert (want is None) == (have is None)
            if want is None or have is None:
                continue
            np.testing.assert_allclose(have.pose, want.pose, atol=1e-5)
            assert have.flags == want.flags
            flags.update(have.flags)
        assert [w.reasons for w in together] == [w.reasons for w in alone]
    assert {"unloaded", "out_of_range"} <= flags
    with pytest.raises(ModelInputError, match="frame must be"):
        push_many(together, np.zeros((3, c.FRAME_ROWS, c.FRAME_COLS), np.uint16))
    assert [w.frames_seen for w in together] == [c.WINDOW + 30] * 3
