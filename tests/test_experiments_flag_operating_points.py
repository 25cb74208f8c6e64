"""experiments/flag_operating_points.py: each calibration choice scored as a trade.

The measurement needs the corpus and a trained checkpoint (a command, docs/ood.md);
what it computes from the pooled vectors is tested here on made-up clouds: a
window is published when right and unflagged, sent wrong when wrong and
unflagged, and a higher percentile flags less.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

EXPERIMENTS = Path(__file__).resolve().parent.parent / "experiments"
sys.path.insert(0, str(EXPERIMENTS))

import flag_operating_points as fop  # noqa: E402


def cloud(rng: np.random.Generator, n: int, centre: float, labels: int) -> fop.Windows:
    pooled = rng.normal(centre, 1.0, (n, 4))
    actions = np.full(n, labels, dtype=np.int64)
    return fop.Windows(pooled, actions, actions.copy(), np.full(n, 0.95))


def test_shares_count_published_right_and_sent_wrong_among_labelled_windows() -> None:
    class FlagsFirstTwo:
        threshold = 0.5

        def score(self, pooled: np.ndarray, predicted: np.ndarray) -> np.ndarray:
            return np.array([1.0, 1.0, 0.0, 0.0, 0.0])

    w = fop.Windows(
        pooled=np.zeros((5, 2)),
        labels=np.array([0, 1, 0, 1, -1]),  # the last is a transition: not counted
        predicted=np.array([0, 0, 0, 0, 0]),
        confidence=np.array([0.99, 0.99, 0.5, 0.95, 0.99]),
    )
    got = fop.shares(FlagsFirstTwo(), w)
    # Of 4 labelled: window 2 right and unflagged; window 3 wrong, unflagged, confident.
    assert got == {
        "published_right": 0.25,
        "wrong_unflagged": 0.25,
        "confident_wrong_unflagged": 0.25,
    }


def test_every_choice_is_scored_and_a_higher_percentile_withholds_less() -> None:
    rng = np.random.default_rng(0)
    train = {side: cloud(rng, 400, 0.0, 0) for side in fop.SIDES}
    held = {side: cloud(rng, 400, 0.0, 0) for side in fop.SIDES}
    far = cloud(rng, 400, 3.0, 0)  # right answers on inputs unlike training
    judges = {"recorded": cloud(rng, 400, 0.0, 0), "as trained": far, "foreign": far}
    rows = fop.operating_points(train, held, judges)
    assert len(rows) == len(fop.SIDES) ** 2 * len(fop.PERCENTILES)
    by_p = [r for r in rows if r["statistics"] == "recorded" and r["threshold"] == "recorded"]
    published = [r["foreign"]["published_right"] for r in by_p]
    assert published == sorted(published)  # 90, 95, 99: ever fewer flagged
    assert published[0] < 0.5  # far windows are mostly flagged
    assert by_p[-1]["recorded"]["published_right"] > 0.95
    text = fop.markdown(rows, "python experiments/flag_operating_points.py --model m")
    for q in ("90", "95", "99"):
        assert text.count(f"\n| recorded | recorded | {q} |") == 1
    assert "| as trained | as trained | 99 |" in text


def test_the_clean_copies_are_left_out_of_the_calibration(tmp_path: Path) -> None:
    for folder in ("realistic", "clean", "slow"):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / "subject-000.ses").write_bytes(b"")
    files = fop.calibration_files(tmp_path)
    assert [f.parent.name for f in files] == ["realistic", "slow"]
