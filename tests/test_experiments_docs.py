"""The experiment drivers' own logic: partitions, budgets, and the docs they write.

The long runs themselves (training, the sweep) are commands, never tests; here
their pieces run on small synthetic inputs: reports made by the real
``scotti.evaluation.evaluation.score`` on random frames.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scotti.evaluation.evaluation import FrameScores, FrameSet, score, task_metrics
from scotti.models.contract import NUM_ACTIONS, has_progress

EXPERIMENTS = Path(__file__).resolve().parent.parent / "experiments"
sys.path.insert(0, str(EXPERIMENTS))
sys.path.insert(0, str(EXPERIMENTS.parent / "scripts"))  # ship_default, the release step

import common  # noqa: E402
import corpus  # noqa: E402
import history_table  # noqa: E402
import partition_runs  # noqa: E402
import partition_table  # noqa: E402
import ship_default  # noqa: E402
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


def test_side_by_side_commands_are_followed_up_as_each_ends(tmp_path: Path) -> None:
    """``then`` runs for a command as soon as it ends, while the slower one still runs."""
    go = tmp_path / "go"
    waits_for_go = (
        f"import pathlib, time\ngo = pathlib.Path({str(go)!r})\n"
        "end = time.monotonic() + 60\n"
        "while not go.exists() and time.monotonic() < end:\n"
        "    time.sleep(0.05)\n"
        "print('went' if go.exists() else 'timed out')\n"
    )
    cmds = [[sys.executable, "-c", waits_for_go], [sys.executable, "-c", "print('quick')"]]
    followed: list[int] = []

    def then(i: int) -> None:
        followed.append(i)
        go.touch()  # only the quick command's follow-up can let the slow one end

    outs = common.run_parallel(cmds, tmp_path / "log", then=then)
    assert outs == ["went\n", "quick\n"]  # stdouts in command order
    assert followed == [1, 0]  # in the order they ended
    assert (tmp_path / "log").read_text().count("$ ") == 2
    # A failed command raises once the others have ended, and is not followed up.
    followed.clear()
    failing = [[sys.executable, "-c", "raise SystemExit(3)"], cmds[1]]
    with pytest.raises(common.ExperimentError, match="status 3"):
        common.run_parallel(failing, tmp_path / "log", then=followed.append)
    assert followed == [1]


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
    action = rng.integers(-1, NUM_ACTIONS, n)  # -1: a transition
    progress = np.where([has_progress(int(a)) for a in action], rng.uniform(0, 1, n), np.nan)
    right = rng.random(n) < quality
    return FrameSet(
        pose_pred=pose + rng.normal(0, 0.1 * (1 - quality), pose.shape).astype(np.float32),
        pose_true=pose,
        action_pred=np.where(right, np.maximum(action, 0), rng.integers(0, NUM_ACTIONS, n)),
        action_true=action,
        progress_pred=np.where(right, np.nan_to_num(progress), rng.uniform(0, 1, n)),
        progress_true=progress,
    )


def _report(frames: FrameSet, variant: str, name: str) -> dict[str, Any]:
    report = score(FrameScores.of(frames))
    report["variant"] = variant
    report["model"] = {"path": f"runs/tables/models/{name}.onnx"}
    report["sessions"] = [
        {"subject": "s", "evaluated": len(frames), "metrics": task_metrics(FrameScores.of(frames))}
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
    # A hand-kept section survives the rewrite; the rest is replaced.
    kept = f"{tables_doc.KEEP_BEGIN}\nfigures of the current corpus\n{tables_doc.KEEP_END}"
    doc.write_text(f"# old title\n\n{kept}\n\nold tables\n")
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
    assert kept in text
    assert "old tables" not in text
    assert text.index(kept) < text.index("## Table 1")
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
    metrics = _metrics(acc)
    return {
        "label": label,
        "config": label,
        "precision": "fp32",
        "T": t,
        "size_mb": mb,
        "latency": {"1": lat, "2": lat},
        "metrics": metrics,
        "per_partition": {"p1": metrics, "p2": metrics},
    }


def _metrics(acc: float, mm: float | None = None) -> dict[str, Any]:
    """Task figures that all get better with ``acc`` (MPJPE from ``mm`` when given)."""
    return {
        "mpjpe_mm": 100 - acc * 10 if mm is None else mm,
        "action_accuracy": acc,
        "progress_mse": 0.1 - acc / 20,
        "app": 0.6 + acc / 5,
        "mpjae_deg": 5.0,
        "frames": 100,
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


PARTS = ("p1", "p2", "p3")


def _sweep(
    tmp_path: Path, accuracy: dict[str, tuple[float, ...]], p99: dict[str, float]
) -> list[dict[str, Any]]:
    """Rows as the sweep builds them: per config, one model per partition (fp32 + int8,
    int8 a point worse), eval reports with the given per-partition accuracies, and the
    latency and card of the first partition's model."""
    models, timed, plans, evaluated, latency = {}, {}, {}, {}, {}
    for name, accs in accuracy.items():
        paths = {p: tmp_path / f"{name}-{p}.onnx" for p in PARTS[: len(accs)]}
        models[name] = paths
        timed[name] = paths["p1"]
        config = {"embed_dim": 128, "layers": 2, "window": 40}
        paths["p1"].with_name(f"{name}-p1.card.json").write_text(
            json.dumps({"config": config, "parameters": 1000})
        )
        for precision, delta in (("", 0.0), (".int8", -0.01)):
            lat = {"step_median_ms": p99[name] / 2, "step_p99_ms": p99[name]}
            lat["window_median_ms"] = p99[name]
            latency[str(paths["p1"]).replace(".onnx", f"{precision}.onnx")] = {
                "bytes": 2e6,
                "step_flops": 1e6,
                "window_flops": 5e6,
                "latency": {"1": lat, "2": lat},
            }
            for (part, path), acc in zip(paths.items(), accs, strict=True):
                report = {"metrics": _metrics(acc + delta, mm=100 + 10 * PARTS.index(part))}
                evaluated[str(path).replace(".onnx", f"{precision}.onnx")] = report
        plans[name] = {
            p: {"trained_s": 60.0 * (1 + i), "epochs": 3, "epochs_done": 3, "stride": 8}
            for i, p in enumerate(paths)
        }
    return sweep_doc.rows_of(models, timed, {}, plans, evaluated, latency)


def test_sweep_rows_are_the_mean_and_spread_over_partitions(tmp_path: Path) -> None:
    rows = _sweep(tmp_path, {"A": (0.6, 0.7, 0.8), "B": (0.5, 0.9)}, {"A": 1.0, "B": 2.0})
    by = {r["label"]: r for r in rows}
    assert set(by) == {"A fp32", "A int8", "B fp32", "B int8"}
    a, q = by["A fp32"], by["A int8"]
    assert a["n"] == 3
    assert a["metrics"]["action_accuracy"] == pytest.approx(0.7)
    assert a["spread"]["action_accuracy"] == pytest.approx(0.1)  # sample SD, not population
    assert a["metrics"]["mpjpe_mm"] == pytest.approx(110.0)  # 100, 110, 120
    assert a["spread"]["mpjpe_mm"] == pytest.approx(10.0)
    assert a["metrics"]["frames"] == 300
    assert q["metrics"]["action_accuracy"] == pytest.approx(0.69)  # int8's own reports
    assert a["per_partition"]["p3"]["action_accuracy"] == 0.8
    assert a["trained_min"] == pytest.approx(2.0)  # mean of 1, 2, 3 minutes
    assert a["epochs"] == "3/3, 3/3, 3/3"
    assert by["B fp32"]["n"] == 2
    assert by["B fp32"]["spread"]["action_accuracy"] == pytest.approx(0.2828, abs=1e-4)


def test_the_default_is_chosen_on_the_means_not_one_partition(tmp_path: Path) -> None:
    # "lucky" has the best p1 figures, "steady" the best mean over the three partitions.
    rows = _sweep(
        tmp_path,
        {"lucky": (0.95, 0.4, 0.4), "steady": (0.75, 0.75, 0.75), "slow": (0.9, 0.9, 0.9)},
        {"lucky": 1.0, "steady": 3.0, "slow": 12.0},
    )
    choice = sweep_doc.choose_default(rows, 10.0)
    assert choice is not None
    assert choice["label"] == "steady fp32"
    assert choice["paths"]["p1"].endswith("steady-p1.onnx")  # what --ship ships


def test_the_sweep_doc_shows_mean_and_spread(tmp_path: Path) -> None:
    rows = _sweep(tmp_path, {"A": (0.6, 0.7, 0.8), "B": (0.8, 0.85, 0.9)}, {"A": 1.0, "B": 2.0})
    choice = sweep_doc.choose_default(rows, 10.0)
    assert choice is not None
    parts = [common.Partition(p, ("a", "b"), (f"{p}-t1", f"{p}-t2")) for p in PARTS]
    doc = tmp_path / "doc.md"
    kept = (
        f"{tables_doc.KEEP_BEGIN}\nfp32 against int8 on the current corpus\n{tables_doc.KEEP_END}"
    )
    doc.write_text(f"# old title\n\n{kept}\n\nold sweep table\n")
    sweep_doc.write_sweep_doc(
        doc,
        tmp_path / "img",
        rows=rows,
        choice=choice,
        limit_ms=10.0,
        partitions=parts,
        every=8,
        share_min=2.5,
        invocation="python experiments/sweep.py --budget-minutes 1",
        commands=["scotti eval x --model y --every 8"],
        written="now",
    )
    text = doc.read_text()
    assert (tmp_path / "img" / "accuracy-vs-latency.png").read_bytes()[:8] == PNG
    table_rows = [ln for ln in text.splitlines() if ln.startswith("| B | fp32 |")]
    assert len(table_rows) == 1
    assert "| 85.0 ± 5.0 |" in table_rows[0]  # accuracy %, mean ± SD over p1..p3
    assert "| 110.0 ± 10.0 |" in table_rows[0]  # MPJPE mm
    assert "mean over the 3 partitions" in text
    assert "p2: held out p2-t1, p2-t2" in text
    assert "every 8th prediction time scored, through the window graph" in text
    assert "2.5 min of budget per run" in text
    assert "**The default** (`models/scotti-default.onnx`): **B fp32**" in text
    assert "scotti eval x --model y --every 8" in text
    assert kept in text  # a rewrite keeps the hand-kept section
    assert "old sweep table" not in text


def test_the_shipped_card_carries_every_partition(tmp_path: Path) -> None:
    reports = []
    for k, p in enumerate(PARTS):
        report = _report(_frames(300, k, 0.5 + 0.1 * k), "multi", f"A-{p}")
        reports.append(report | {"partition": p, "every": 8})
    block = ship_default.evaluation_block(reports, ["scotti eval a", "scotti eval b"])
    assert block["spread_over"] == "partitions"
    assert [p["partition"] for p in block["partitions"]] == list(PARTS)
    accs = [r["metrics"]["action_accuracy"] for r in reports]
    mean, sd = common.mean_sd(accs)
    assert block["summary"]["action_accuracy"] == {"mean": mean, "sd": sd, "n": 3}
    assert sd > 0
    assert "every 8th prediction time" in block["how"]
    standing = block["per_action"]["standing"]  # scored like any action, pooled
    frames = [r["per_action"]["standing"]["frames"] for r in reports]
    assert standing["frames"] == sum(frames) > 0
    recall = [r["per_action"]["standing"]["action_accuracy"] for r in reports]
    assert min(recall) <= standing["action_accuracy"] <= max(recall)


def test_the_card_names_each_partitions_own_model(tmp_path: Path) -> None:
    paths = []
    for k, p in enumerate(PARTS):
        report = _report(_frames(300, 40 + k, 0.6), "multi", f"run-{p}")
        paths.append(tmp_path / f"{p}.json")
        other = report | {"model": {"path": "runs/tables/models/other.onnx"}}
        paths[-1].write_text(json.dumps([report, other]))  # only the first is the partition's
    reports = ship_default.load_reports(
        [f"{p}={path}" for p, path in zip(PARTS, paths, strict=True)]
    )
    assert [r["partition"] for r in reports] == list(PARTS)
    block = ship_default.evaluation_block(reports, ["scotti eval a"])
    assert [p["model"] for p in block["partitions"]] == [
        f"runs/tables/models/run-{p}.onnx" for p in PARTS
    ]
    lines = [ln for ln in _card_lines(block) if ln.startswith("- p")]
    assert [ln.split(" (model ")[0] for ln in lines] == [f"- {p}" for p in PARTS]
    assert all(
        f"`runs/tables/models/run-{p}.onnx`" in ln for p, ln in zip(PARTS, lines, strict=True)
    )
    # Without a name the report keeps the sweep's own partition key (none here).
    unnamed = ship_default.load_reports([str(paths[0])])
    assert len(unnamed) == 2
    assert "partition" not in unnamed[0]


def _card_lines(block: dict[str, Any]) -> list[str]:
    """The held-out section of card_md, cut out of a card built around ``block``."""
    text = ship_default.card_md(
        {
            "name": "n",
            "model": "m",
            "contract_version": 2,
            "precision": "fp32",
            "parameters": 1,
            "shipped_utc": "now",
            "config": {
                k: 1
                for k in ("window", "embed_dim", "layers", "heads", "conv_channels", "head_hidden")
            },
            "normalisation": "x",
            "timing": "t",
            "shipped_data": "d",
            "evaluation": block,
            "latency": {"measured_utc": "now", "machine": "m", "by_threads": {}},
            "flops": {"step": 1, "window": 1},
            "files": {},
            "parity": {"tolerance": {"atol": 1e-4}},
            "shipped_from": "c",
        }
    )
    start = text.index("## Held-out metrics")
    return text[start : text.index("## What it does not know", start)].splitlines()


def test_the_partition_table_scores_each_partition_and_refuses_a_seen_subject(
    tmp_path: Path,
) -> None:
    specs = []
    for k, p in enumerate(PARTS):
        report = _report(_frames(300, 60 + k, 0.5 + 0.2 * k), "multi", f"run-{p}")
        report["random_baseline"] = {"action_accuracy": 0.1, "progress_mse": 0.2, "app": 0.65}
        report["ood"] = {"unloaded": 0.01 * k, "out_of_range": 0.0, "unfamiliar": 0.002}
        (tmp_path / f"{p}.json").write_text(json.dumps([report]))
        specs.append(f"{p}={tmp_path / p}.json")
    doc = tmp_path / "doc.md"
    doc.write_text(f"head\n{partition_table.BEGIN}\nold\n{partition_table.END}\ntail\n")
    img = tmp_path / "img"
    clean_report = json.loads((tmp_path / "p1.json").read_text())[0]
    clean_report["metrics"] = clean_report["metrics"] | {"action_accuracy": 0.25}
    (tmp_path / "p1-clean.json").write_text(json.dumps(clean_report))
    clean = ["--clean", f"p1={tmp_path / 'p1-clean.json'}"]
    assert partition_table.main([*specs, "--write", str(doc), "--img", str(img), *clean]) == 0
    text = doc.read_text()
    for name in ("partitions-confusion.png", "partitions-precision-margin.png"):
        assert (img / name).read_bytes()[:8] == PNG
        assert f"(img/{name})" in text  # linked relative to the doc
    assert text.startswith("head\n")
    assert text.endswith(f"{partition_table.END}\ntail\n")
    assert "old" not in text
    rows = [ln for ln in text.splitlines() if ln.startswith(("| p1 ", "| p2 ", "| p3 "))]
    assert [r.split(" | ")[0] for r in rows] == ["| p1", "| p2", "| p3"]
    assert "| 0.00 % / 0.00 % / 0.20 % |" in rows[0]
    assert "| 2.00 % / 0.00 % / 0.20 % |" in rows[2]
    accs = []
    for p in PARTS:
        accs.append(
            json.loads((tmp_path / f"{p}.json").read_text())[0]["metrics"]["action_accuracy"]
        )
    ours = next(ln for ln in text.splitlines() if ln.startswith("| SCOTTI, ours (multi"))
    assert common.fmt(accs, 2, 100) in ours
    clean_row = next(ln for ln in text.splitlines() if "without sensor/transport" in ln)
    assert "| 25.00 |" in clean_row  # one partition's clean copy: its figure, no spread
    # A clean report of another model (or other people) is refused.
    other = clean_report | {"subjects": ["subject-099"]}
    (tmp_path / "p1-other.json").write_text(json.dumps(other))
    assert partition_table.main([*specs, "--clean", f"p1={tmp_path / 'p1-other.json'}"]) == 1
    # A model that trained on a subject it is scored on is refused.
    graph = tmp_path / "seen.onnx"
    report = _report(_frames(50, 1, 0.5), "multi", "seen") | {"subjects": ["subject-007"]}
    report["model"] = {"path": str(graph)}
    (tmp_path / "seen.card.json").write_text(
        json.dumps({"training_data": {"subjects": ["subject-001", "subject-007"]}})
    )
    (tmp_path / "seen.json").write_text(json.dumps(report))
    assert partition_table.main([f"p1={tmp_path / 'seen.json'}"]) == 1


def test_a_second_recipes_partition_table_goes_into_its_own_section(tmp_path: Path) -> None:
    specs = []
    for k, p in enumerate(PARTS):
        report = _report(_frames(200, 70 + k, 0.6), "multi", f"run-{p}")
        (tmp_path / f"{p}.json").write_text(json.dumps([report]))
        specs.append(f"{p}={tmp_path / p}.json")
    first = f"{partition_table.BEGIN}\nkept\n{partition_table.END}\n"
    doc = tmp_path / "doc.md"
    doc.write_text(f"{first}between\n<!-- v12:begin -->\nold\n<!-- v12:end -->\n")
    img = tmp_path / "img"
    argv = [*specs, "--write", str(doc), "--img", str(img), "--section", "v12"]
    assert partition_table.main(argv) == 0
    text = doc.read_text()
    assert text.startswith(first + "between\n")  # the first recipe's table is untouched
    assert "old" not in text
    assert "| p3 |" in text
    for name in ("v12-confusion.png", "v12-precision-margin.png"):
        assert (img / name).read_bytes()[:8] == PNG
        assert f"(img/{name})" in text
    assert not (img / "partitions-confusion.png").exists()
    # A section the doc does not have is refused, and the doc is left as it was.
    assert partition_table.main([*specs, "--write", str(doc), "--section", "v13"]) == 1
    assert doc.read_text() == text


def _epoch(epoch: int, train: float, val: float) -> dict[str, Any]:
    figures = {"action_accuracy": 0.9, "progress_mse": 0.02, "app": 0.91, "mpjpe_mm": 55.0}
    return {"epoch": epoch, "train_loss": train, "val": {"loss": val, **figures}}


def test_the_history_table_bolds_the_best_epoch_of_each_run(tmp_path: Path) -> None:
    for name, vals in (("a", (1.0, 0.7, 0.8)), ("b", (0.9, 0.95))):
        (tmp_path / name).mkdir()
        lines = [json.dumps(_epoch(k + 1, 2.0 - k, v)) for k, v in enumerate(vals)]
        (tmp_path / name / "history.jsonl").write_text("\n".join(lines) + "\n")
    doc = tmp_path / "doc.md"
    doc.write_text("<!-- epochs:begin -->\nold\n<!-- epochs:end -->\n")
    specs = [f"a={tmp_path / 'a'}", f"b={tmp_path / 'b'}"]
    assert history_table.main([*specs, "--write", str(doc)]) == 0
    rows = [ln for ln in doc.read_text().splitlines() if ln.startswith(("| a ", "| b "))]
    assert [r.split(" | ")[1] for r in rows] == ["1", "2", "3", "1", "2"]
    bold = [r.split(" | ")[:2] for r in rows if "**" in r]
    assert bold == [["| a", "2"], ["| b", "1"]]  # each run's lowest validation loss
    assert "| 90.0 % | 0.0200 | 0.910 | 55.0 |" in rows[0]
    # A run without a history, or with a broken line, is refused with the file named.
    assert history_table.main([f"c={tmp_path / 'c'}"]) == 1
    for broken in ('{"epoch": 1}\n', '{"epoch": 1, "train_loss": 1.0}\n{"train_lo'):
        (tmp_path / "b" / "history.jsonl").write_text(broken)
        assert history_table.main([f"b={tmp_path / 'b'}"]) == 1


def test_a_partition_run_never_gives_its_test_subjects_to_training(tmp_path: Path) -> None:
    corpus = tmp_path / "corpus"
    for part, ids in (("realistic", range(15)), ("extra", range(15, 33))):
        (corpus / part).mkdir(parents=True)
        for i in ids:
            (corpus / part / f"subject-{i:03d}.ses").write_bytes(b"")
    p2 = next(p for p in common.load_partitions() if p.name == "p2")
    job = partition_runs.PartitionRun("p2", p2.train, p2.test, tmp_path / "run")
    # The script's own parser, so every option it passes on has its default.
    argv = ["p2", "--lr", "1e-3", "--max-minutes", "30", "--cache", "c"]
    opts = partition_runs.build_parser().parse_args(argv)
    cmd = [str(x) for x in job.train_command(corpus, opts)]
    stems = {Path(w).stem for w in cmd if w.endswith(".ses")}
    assert not stems & set(p2.test)
    assert stems == set(p2.train) | {f"subject-{i:03d}" for i in range(15, 33)}
    val = cmd[cmd.index("--val-subjects") + 1 : cmd.index("--test-fraction")]
    assert val == [*p2.train[-2:], "subject-031", "subject-032"]
    assert cmd[cmd.index("--loss-weights") + 1] == "0.01,1,3"
    assert "--resume" not in cmd
    assert not job.finished(8)
    job.run_dir.mkdir()
    (job.run_dir / "last.pt").write_bytes(b"")
    assert "--resume" in [str(x) for x in job.train_command(corpus, opts)]
    history = job.run_dir / "history.jsonl"
    history.write_text('{"epoch": 1}\n{"epoch": 2}\n')
    assert not job.finished(8)  # --max-minutes stopped it: it resumes
    history.write_text('{"epoch": 1}\n{"epoch": 2, "status": "plateau"}\n')
    assert job.finished(8)
    assert partition_runs.main(["p9"]) == 1


def test_more_people_train_beside_the_partition_and_never_its_tests(tmp_path: Path) -> None:
    corpus = tmp_path / "corpus"
    for part, ids in (("realistic", range(15)), ("extra", range(15, 33)), ("more", range(33, 36))):
        (corpus / part).mkdir(parents=True)
        for i in ids:
            (corpus / part / f"subject-{i:03d}.ses").write_bytes(b"")
    argv = ["p1", "--more", "more", "--threads", "2", "--corpus", str(corpus), "--cache", "c"]
    opts = partition_runs.build_parser().parse_args(argv)
    (job,) = partition_runs.plan(opts)
    assert job.run_dir.name == "v9-p1-more"
    cmd = [str(x) for x in job.train_command(corpus, opts)]
    stems = {Path(w).stem for w in cmd if w.endswith(".ses")}
    p1 = next(p for p in common.load_partitions() if p.name == "p1")
    assert stems == set(p1.train) | {f"subject-{i:03d}" for i in range(15, 36)}
    assert not stems & set(p1.test)
    assert cmd[cmd.index("--threads") + 1] == "2"
    # The held-out files and the validation subjects are as without --more.
    assert {f.stem for f in job.files(corpus, job.test)} == set(p1.test)
    assert job.validation == (*p1.train[-2:], "subject-031", "subject-032")
    empty = partition_runs.build_parser().parse_args(["p1", "--more", "none"])
    (nothing,) = partition_runs.plan(empty)
    with pytest.raises(common.ExperimentError, match="no session files"):
        nothing.files(corpus)


def test_a_graph_scored_beside_joins_only_its_partitions_replay(tmp_path: Path) -> None:
    shipped = tmp_path / "shipped.onnx"
    shipped.write_bytes(b"")
    argv = ["p1", "p2", "--beside", f"p1={shipped}", "--cache", "c"]
    p1_job, p2_job = partition_runs.plan(partition_runs.build_parser().parse_args(argv))
    model, before = tmp_path / "m.onnx", tmp_path / "before.onnx"
    both = ["--model", model, "--model", before]
    assert p1_job.eval_models(model, before) == [*both, "--model", shipped]
    assert p2_job.eval_models(model, before) == both
    for bad, why in (
        (f"p3={shipped}", "not among"),
        ("p1", "expected NAME=PATH"),
        (f"p1={tmp_path / 'none.onnx'}", "no such model"),
    ):
        opts = partition_runs.build_parser().parse_args(["p1", "p2", "--beside", bad])
        with pytest.raises(common.ExperimentError, match=why):
            partition_runs.plan(opts)


def test_the_cards_training_section_says_the_recipe_the_checkpoint_recorded(
    tmp_path: Path,
) -> None:
    torch = pytest.importorskip("torch")
    import card_training

    run = tmp_path / "run"
    run.mkdir()
    val = {"loss": 1.0, "mpjpe_mm": 60.0, "action_accuracy": 0.9, "progress_mse": 0.03, "app": 0.9}
    record = {"epoch": 1, "train_loss": 2.0, "seconds": 60.0, "val": val, "best_epoch": 1}
    (run / "history.jsonl").write_text(json.dumps(record | {"status": "plateau"}) + "\n")
    options = {
        "epochs": 8,
        "stride": 16,
        "lr": 1e-3,
        "loss_weights": {"pose": 0.01, "action": 1.0, "progress": 3.0},
        "max_shift": 2,
        "max_crosstalk": 0.03,
        "ema": 0.999,
        "progress_bar": False,  # not part of the recipe
    }
    torch.save({"options": options}, run / "best.pt")
    text = "\n".join(card_training.training_markdown(card_training.training_block(run / "best.pt")))
    recipe = next(ln for ln in text.splitlines() if ln.startswith("Recipe"))
    assert "loss_weights (pose 0.01, action 1, progress 3)" in recipe
    assert "max_crosstalk 0.03" in recipe
    assert "ema 0.999" in recipe
    assert "stride 16" in recipe
    assert "progress_bar" not in recipe
    # A checkpoint from before the crosstalk and average options was trained without them.
    older = {k: v for k, v in options.items() if k not in ("max_crosstalk", "ema")}
    torch.save({"options": older}, run / "best.pt")
    block = card_training.training_block(run / "best.pt")
    assert block is not None
    assert block["recipe"]["max_crosstalk"] == 0.0
    assert block["recipe"]["ema"] == 0.0
    (run / "best.pt").write_bytes(b"not a checkpoint")
    block = card_training.training_block(run / "best.pt")
    assert block is not None
    assert block["recipe"] is None
    assert not any(ln.startswith("Recipe") for ln in card_training.training_markdown(block))
