"""experiments/flag_threshold_noise.py: the flag's thresholds refitted as export fits them.

The measurement needs the corpus, the real files and a shipped model (a command,
docs/ood.md); what it computes is tested here on made-up clouds: the refitted
thresholds are the ones models/ood.py's ``fit`` writes into a graph, and the
published share counts what a subscriber would get.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

EXPERIMENTS = Path(__file__).resolve().parent.parent / "experiments"
sys.path.insert(0, str(EXPERIMENTS))

import flag_threshold_noise as ftn  # noqa: E402
from scotti.models.contract import ACTIONS  # noqa: E402
from scotti.models.ood import fit  # noqa: E402

WALKING = ACTIONS.index("walking")
STANDING = ACTIONS.index("standing")


def clouds(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Pooled vectors of two actions around two centres, and their labels."""
    labels = np.where(np.arange(n) % 2 == 0, WALKING, STANDING)
    centres = np.where(labels[:, None] == WALKING, 3.0, -3.0)
    return rng.normal(centres, 1.0, (n, 6)), labels


def test_refitted_thresholds_are_the_ones_export_fits() -> None:
    rng = np.random.default_rng(4)
    train, train_labels = clouds(rng, 400)
    held, held_labels = clouds(rng, 300)
    held_labels[:40] = STANDING  # the model gets some wrong: thresholds go by prediction
    stats = fit(train, held, 99.0, train_labels, held_labels)
    assert stats.action_means is not None
    d = ftn.distances(stats, held)
    refitted = ftn.fit_thresholds(d, held_labels, stats.action_means.actions)
    np.testing.assert_allclose(refitted, stats.action_means.thresholds, rtol=1e-5)
    # A lower percentile's thresholds are lower: the refit reads the percentile it is given.
    fewer = ftn.fit_thresholds(d[:150], held_labels[:150], stats.action_means.actions)
    assert not np.allclose(fewer, refitted)


def test_published_counts_walking_read_right_unflagged_and_with_clean_inputs() -> None:
    rows = np.full(len(ACTIONS), -1)
    rows[WALKING], rows[STANDING] = 0, 1
    th = np.array([2.0, 2.0])
    f = ftn.RealWindows(
        name="x",
        walking=np.array([True, True, True, True, True, False]),
        predicted=np.array([WALKING, WALKING, WALKING, STANDING, ACTIONS.index("jump"), WALKING]),
        # distance to the walking mean (column 0) and to standing's (column 1)
        distances=np.array([[1.0, 5], [3.0, 5], [1.0, 5], [5, 1.0], [1.0, 1.0], [1.0, 5]]),
        inputs_ok=np.array([True, True, False, True, True, True]),
    )
    # Of the 5 walking windows: the first is published; the second is flagged, the
    # third fails the input checks, the fourth says standing, the fifth jump (an
    # action without a mean here). The sixth is not a walking window.
    assert ftn.published_share([f], rows, th) == pytest.approx(1 / 5)
    assert ftn.published_share([f], rows, np.array([4.0, 2.0])) == pytest.approx(2 / 5)
