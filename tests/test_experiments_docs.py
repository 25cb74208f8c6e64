"""The experiment drivers' own logic: partitions, budgets, and the docs they write.

The long runs themselves (training, the sweep) are commands, never tests; here
their pieces run on small synthetic inputs: reports made by the real
``scotti.daemon.evaluation.score`` on random frames.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np
from scotti.daemon.evaluation import FrameSet, score, task_metrics

EXPERIMENTS = Path(__file__).resolve().parent.parent / "experiments"
sys.path.insert(0, str(EXPERIMENTS))

import common  # noqa: E402
import corpus  # noqa: E402
import sweep_doc  # noqa: E402
import tables_doc  # noqa: E402
import training  # noqa: E402

PNG = b"\x89PNG\r\n\x1a\n"


def test_partitions_are_subject_wise_with_disjoint_test_sets() -> None:
    ids = [f"subject-{i:03d}" for i in range(15)]
    parts = corpus.partitions(ids)
    assert len(parts) == 3
    tested: list[str] = []
    for p in parts:
        assert len(p["train"]) == 10
        assert len(p["test"]) == 5
        assert not set(p["train"]) & set(p["test"])
        tested += p["test"]
    assert sorted(tested) == ids  # every subject is tested exactly once
    assert corpus.partitions(ids) == parts  # seeded


def test_mean_spread_and_formatting() -> None:
    assert common.mean_sd([1.0, 2.0, 3.0]) == (2.0, 1.0)
    assert common.fmt([0.5, 0.7], 1, 100) == "60.0 ± 14.1"
    assert common.fmt([0.5], 2) == "0.50"  # one value has no spread
    assert common.fmt([float("nan")], 2) == "-"


def test_a_plan_fits_its_budget() -> None:
    part = common.Partition("p1", ("a",), ("b",))
    spec = training.RunSpec(Path("runs/x"), part, "small")
    for budget_s, windows in ((120, 150_000), (600, 150_000), (120, 10_000), (30, 900_000)):
        plan = training.plan(spec, budget_s=budget_s, rate=100.0, windows=windows)
        assert 2 <= plan["stride"] <= training.MAX_STRIDE
        assert 1 <= plan["epochs"] <= training.EPOCHS
        seen = plan["epochs"] * windows / plan["stride"]
        # Planned epochs fit in 60 % of the budget, unless even one cannot.
        assert seen <= 0.6 * budget_s * 100 * 1.01 or plan["epochs"] == 1
    assert plan["loss_weights"] == "0.01,1,1"


def _frames(n: int, seed: int, quality: float) -> FrameSet:
    """Random labelled frames and predictions that are right with probability ``quality``."""
    rng = np.random.default_rng(seed)
    pose = rng.normal(0, 0.3, (n, 19, 3)).astype(np.float32)
    action = rng.integers(-1, 8, n)
    progress = np.where(action >= 0, rng.uniform(0, 1, n), np.nan)
    right = rng.random(n) < quality
    return FrameSet(
        pose_pred=pose + rng.normal(0, 0.1 * (1 - quality), pose.shape).astype(np.float32),
        pose_true=pose,
        action_pred=np.where(right, np.maximum(action, 0), rng.integers(0, 8, n)),
        action_true=action,
        progress_pred=np.where(right, np.nan_to_num(progress), rng.uniform(0, 1, n)),
        progress_true=progress,
    )


def _report(frames: FrameSet, variant: str, name: str) -> dict[str, Any]:
    report = score(frames)
    report["variant"] = variant
    report["model"] = {"path": f"runs/tables/models/{name}.onnx"}
    report["sessions"] = [
        {"subject": "s", "evaluated": len(frames), "metrics": task_metrics(frames)}
    ]
    report["subjects"] = ["s"]
    return report


def test_the_evaluation_doc_holds_the_tables_and_figures(tmp_path: Path) -> None:
    parts = [common.Partition(f"p{k}", ("a", "b"), (f"t{k}",)) for k in (1, 2, 3)]
    results = {
        p.name: [
            _report(_frames(400, 10 * k + i, q), v, f"{p.name}-{v}")
            for i, (v, q) in enumerate(
                [("multi", 0.8), ("pose", 0.6), ("action", 0.6), ("progress", 0.6)]
            )
        ]
        for k, p in enumerate(parts)
    }
    plans = {
        (p.name, v): {
            "config": "small",
            "variant": v,
            "loss_weights": "0.01,1,1",
            "budget_s": 60.0,
            "measured_windows_per_s": 100.0,
            "epochs": 3,
            "epochs_done": 3,
            "stride": 8,
            "trained_s": 60.0,
            "status": "done",
            "commands": [f"scotti train {p.name} {v}"],
        }
        for p in parts
        for v in training.VARIANTS
    }
    doc = tmp_path / "evaluation.md"
    tables_doc.write_evaluation_doc(
        doc,
        tmp_path / "img",
        partitions=parts,
        corpus={
            "subjects": 15,
            "minutes_per_action": 2,
            "total_hours": 4,
            "seed": 1,
            "effects": ["noise"],
            "realistic": "data/r",
            "clean": "data/c",
        },
        plans=plans,
        results=results,
        invocation="python experiments/paper_tables.py --budget-minutes 1",
        commands=["scotti eval x --model y"],
        written="now",
    )
    text = doc.read_text()
    multi = [r[0] for r in results.values()]
    accuracy = common.fmt([r["metrics"]["action_accuracy"] for r in multi], 2, 100)
    assert "| SCOTTI, ours (multi-task) | " in text
    assert accuracy in text  # the mean ± spread of what eval reported
    assert "Random (uniform progress" in text
    assert "Does sharing help?" in text
    assert "sharing helps here" in text  # multi is built to be the better one
    assert "not the paper's recordings" in text
    assert "scotti train p1 multi" in text
    for png in ("confusion.png", "precision-margin.png"):
        assert (tmp_path / "img" / png).read_bytes()[:8] == PNG
        assert f"img/{png}" in text


def _row(label: str, t: int, p99: float, acc: float, mb: float) -> dict[str, Any]:
    lat = {"step_median_ms": p99 / 2, "step_p99_ms": p99, "window_median_ms": p99}
    return {
        "label": label,
        "config": label,
        "precision": "fp32",
        "T": t,
        "size_mb": mb,
        "latency": {"1": lat, "2": lat},
        "metrics": {
            "mpjpe_mm": 100 - acc * 10,
            "action_accuracy": acc,
            "progress_mse": 0.1 - acc / 20,
            "app": 0.6 + acc / 5,
            "mpjae_deg": 5.0,
        },
    }


def test_the_default_is_the_most_accurate_that_fits(tmp_path: Path) -> None:
    rows = [
        _row("fast", 40, 1.0, 0.5, 2.0),
        _row("good", 40, 6.0, 0.7, 7.0),
        _row("best-but-slow", 40, 25.0, 0.9, 60.0),
        _row("short-window", 20, 2.0, 0.8, 7.0),  # the daemon cannot run T=20
        _row("big", 40, 5.0, 0.85, 30.0),  # over the size limit
    ]
    choice = sweep_doc.choose_default(rows, 10.0)
    assert choice is not None
    assert choice["label"] == "good"
    assert sweep_doc.choose_default(rows, 0.5) is None
    png = sweep_doc.pareto_plot(rows, tmp_path, 10.0)
    assert png.read_bytes()[:8] == PNG
    advice = "\n".join(sweep_doc.advice(rows, choice, 10.0))
    assert "**good**" in advice
    assert "**fast**" in advice
