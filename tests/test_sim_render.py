"""``sim.render.load_span``: the feet drawn are the pairs the daemon shows the model."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scotti.sim.render import load_span

from tests.support.export_sessions import foot_counts, label_for, write_session


def test_a_span_holds_the_daemon_s_pairs_lost_frames_held_lost_rows_patched(
    tmp_path: Path,
) -> None:
    path = write_session(
        tmp_path / "s.scotti", 60, first_seq=65536 - 10, drop_foot=[(20, 1)], drop_rows=[(30, 0, 0)]
    )
    span = load_span(path)
    assert span.counts.shape == (60, 2, 32, 22)
    for k in (0, 9, 10, 59):  # across the wrap
        assert np.array_equal(span.counts[k, 0], foot_counts(k, 0))
        assert np.array_equal(span.counts[k, 1], foot_counts(k, 1))
        assert np.array_equal(span.keypoints[k], label_for(k)[0])
    assert np.array_equal(span.counts[20, 1], foot_counts(19, 1))  # held, as the daemon does
    assert np.array_equal(span.counts[30, 0, :8], foot_counts(29, 0)[:8])  # rows patched
    assert np.array_equal(span.counts[30, 0, 8:], foot_counts(30, 0)[8:])
    assert np.allclose(np.diff(span.time_s), 0.0625)
