"""The input checks' statistics: the wire's uint16 counts give what their float copies
give, and one batch's codes are its frames' checks."""

from __future__ import annotations

import numpy as np
from scotti.models.contract import FRAME_COLS, FRAME_ROWS, MAX_COUNT
from scotti.models.input_checks import (
    frame_stats,
)
from scotti.models.insole import insole_mask


def mixed_frames(rng: np.random.Generator, n: int) -> np.ndarray:
    """uint16 frames (N, H, 2W) that reach every statistic: light and heavy loads inside
    the outline, load outside it, the rail, one hot taxel, empty frames and feet."""
    mask = np.concatenate([insole_mask(), insole_mask()], axis=1)
    x = rng.gamma(0.8, 400.0, (n, FRAME_ROWS, 2 * FRAME_COLS)) * mask
    x[n // 5 : n // 4] = rng.integers(0, MAX_COUNT // 3, (n // 4 - n // 5, *x.shape[1:]))
    x[n // 4 : n // 3] = np.where(mask, MAX_COUNT, 0)  # at the rail
    x[n // 3 : n // 3 + 3] = 0  # nobody there
    x[n // 2 : n // 2 + 4, :, FRAME_COLS:] = 0  # the right foot empty
    x[n // 2 + 5, 10, 5] = MAX_COUNT * 4  # above the counts' range: read as MAX_COUNT
    x[n // 2 + 6] = 0
    x[n // 2 + 6, 10, 5] = 3000  # one hot taxel
    return np.asarray(np.minimum(x, np.iinfo(np.uint16).max), dtype=np.uint16)


def test_counts_as_uint16_give_the_statistics_of_the_same_counts_as_floats() -> None:
    counts = mixed_frames(np.random.default_rng(1), 200)
    ints, floats = frame_stats(counts), frame_stats(counts.astype(np.float32))
    np.testing.assert_allclose(ints.force_n, floats.force_n, rtol=1e-12)
    for name in ("outside_share", "rail_share", "peak_share"):
        np.testing.assert_array_equal(getattr(ints, name), getattr(floats, name))
    assert ints.implausible.any()
    assert not ints.implausible.all()
    assert (ints.rail_share > 0).any()
    assert (~ints.loaded).any()
