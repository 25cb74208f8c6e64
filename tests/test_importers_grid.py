"""Grid mapping: overlap weights, orientation and the area-weighted remap, by hand."""

from __future__ import annotations

import numpy as np
import pytest
from scotti.importers.grid import GridMapper, Orientation, overlap_weights
from scotti.models.insole import insole_mask


def test_overlap_weights_by_hand() -> None:
    np.testing.assert_allclose(overlap_weights(2, 3), [[1, 0], [0.5, 0.5], [0, 1]])
    np.testing.assert_allclose(overlap_weights(1, 4), np.ones((4, 1)))
    # 8 source columns onto 22: target column 2 spans [2/22, 3/22]; source column 0
    # ends at 1/8, so 3/4 of it is over source 0 and 1/4 over source 1.
    w = overlap_weights(8, 22)
    np.testing.assert_allclose(w[2, :2], [0.75, 0.25])
    np.testing.assert_allclose(w.sum(axis=1), 1.0)
    # Each source cell's area goes somewhere in full: columns sum to 22/8.
    np.testing.assert_allclose(w.sum(axis=0), 22 / 8)


def test_orientation_turns_any_layout_into_ours() -> None:
    ours = np.arange(12.0).reshape(1, 4, 3)  # toes at row 0, medial at column 0
    np.testing.assert_array_equal(Orientation().apply(ours), ours)
    stored = ours[:, ::-1, ::-1]  # toes last, medial last
    np.testing.assert_array_equal(Orientation(False, False).apply(stored), ours)
    across = np.swapaxes(ours, 1, 2)  # rows run across the foot
    np.testing.assert_array_equal(Orientation(transpose=True).apply(across), ours)


def test_remap_of_one_hot_taxel_by_hand_and_force_kept() -> None:
    # A 16 x 11 grid: each source taxel covers exactly 2 x 2 of ours.
    frame = np.zeros((1, 16, 11))
    frame[0, 8, 5] = 100.0  # mid-foot, well inside our outline
    out = GridMapper(16, 11)(frame)[0]
    np.testing.assert_allclose(out[16:18, 10:12], 100.0)
    assert np.count_nonzero(out) == 4
    # Force = pressure x area is the same on both grids (all of it inside the outline).
    assert out.sum() / (32 * 22) == pytest.approx(frame.sum() / (16 * 11))


def test_remap_spreads_by_shared_area() -> None:
    frame = np.zeros((1, 32, 8))
    frame[0, 20, 0] = 80.0  # source column 0 = [0, 1/8] across
    out = GridMapper(32, 8)(frame)[0]
    mask = insole_mask()
    expected = np.zeros(22)
    expected[[0, 1]] = 80.0  # [0, 2/22] lies inside [0, 1/8]
    expected[2] = 0.75 * 80.0  # as in the weights test
    np.testing.assert_allclose(out[20], expected * mask[20], rtol=1e-6)


def test_outlines_zero_what_has_no_taxel() -> None:
    frame = np.full((1, 32, 22), 50.0)
    source_mask = np.ones((32, 22), dtype=bool)
    source_mask[:, :11] = False  # the medial half has no taxels
    out = GridMapper(32, 22, source_mask)(frame)[0]
    mask = insole_mask()
    assert (out[~mask] == 0).all()  # ours: nothing outside our outline
    assert (out[:, :11] == 0).all()
    np.testing.assert_allclose(out[:, 11:][mask[:, 11:]], 50.0)
