"""experiments/ood_scores.py: a copy of the shipped graphs carrying other statistics.

The comparison itself needs the corpus (a command, docs/ood.md); what it relies on
is tested here: the copy holds the new statistics in both graphs, the daemon's
runtime loads and scores with them, and the weights are the shipped ones.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

EXPERIMENTS = Path(__file__).resolve().parent.parent / "experiments"
sys.path.insert(0, str(EXPERIMENTS))

import ood_scores  # noqa: E402

MODEL = Path(__file__).resolve().parent.parent / "models" / "scotti-default.onnx"


def test_a_copy_carries_the_new_statistics_in_both_graphs(tmp_path: Path) -> None:
    from scotti.models.kv_streaming import open_step_model
    from scotti.models.ood import fit
    from scotti.models.runtime import ScottiRuntime, window_graph_for

    shipped = ScottiRuntime(window_graph_for(MODEL))
    assert shipped.ood is not None
    rng = np.random.default_rng(0)
    pooled = rng.normal(size=(300, shipped.embed_dim))
    stats = fit(pooled, pooled[:100])  # one global mean: unlike the shipped statistics
    copy = ood_scores.write_copy(MODEL, stats, tmp_path / "global")
    assert copy == tmp_path / "global" / MODEL.name
    window = ScottiRuntime(window_graph_for(copy))
    step = open_step_model(copy, threads=1)
    for runtime in (window, step):
        assert runtime.ood is not None
        assert runtime.ood.action_means is None
        assert runtime.ood.threshold == stats.threshold
    assert shipped.ood.action_means is not None
    frames = rng.uniform(0, 1500, (2, window.window, *window.frame_shape)).astype(np.float32)
    mine, theirs = window.run_windows(frames), shipped.run_windows(frames)
    np.testing.assert_array_equal(mine.pose, theirs.pose)  # the same weights
    assert mine.pooled is not None
    assert mine.unfamiliar_score is not None
    np.testing.assert_allclose(mine.unfamiliar_score, stats.score(mine.pooled), rtol=1e-6)
