"""The per-partition comparisons: multi- against single-task, fp32 against int8."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path
from typing import Any

import pytest
from scotti.models.runtime import ScottiRuntime, window_graph_for

from tests.support.export_sessions import write_session
from tests.support.fixtures_models import always_standing
from tests.test_experiments_docs import EXPERIMENTS, _frames, _report

sys.path.insert(0, str(EXPERIMENTS))

import arch_table
import common
import configs
import effect_ablation
import partition_precision
import partition_runs
import recipe_table
import task_table


def _write(path: Path, report: dict[str, Any]) -> str:
    path.write_text(json.dumps([report]))
    return str(path)


def _specs(tmp_path: Path, reports: dict[str, dict[str, Any]]) -> list[str]:
    """KEY=REPORT arguments of the table scripts, each report written to its own file."""
    return [
        f"{key}={_write(tmp_path / (key.replace(':', '-') + '.json'), report)}"
        for key, report in reports.items()
    ]


def test_the_task_table_pairs_each_single_task_with_its_partitions_multi_task_model(
    tmp_path: Path,
) -> None:
    reports = {
        key: _report(_frames(400, seed, quality), "x", key.replace(":", "-"))
        for seed, (key, quality) in enumerate(
            [
                ("multi:p1", 0.9),
                ("progress:p1", 0.6),
                ("action:p1", 0.5),
                ("multi:p2", 0.8),
                ("progress:p2", 0.7),
            ]
        )
    }
    specs = _specs(tmp_path, reports)
    doc = tmp_path / "doc.md"
    doc.write_text(f"head\n{task_table.BEGIN}\nold\n{task_table.END}\ntail\n")
    assert task_table.main([*specs, "--write", str(doc)]) == 0
    text = doc.read_text()
    assert text.startswith("head\n")
    assert text.endswith(f"{task_table.END}\ntail\n")
    assert "old" not in text
    rows = {
        ln.split(" | ")[0][2:]: ln.removesuffix(" |").split(" | ")
        for ln in text.splitlines()
        if ln.startswith("| ")
    }

    def metric(key: str, who: str) -> list[float]:
        parts = ["p1", "p2"] if who != "action" else ["p1"]
        return [reports[f"{who}:{p}"]["metrics"][key] for p in parts]

    mse = rows["progress MSE"]
    assert mse[1] == "p1, p2"  # paired over both partitions
    assert mse[2] == common.fmt(metric("progress_mse", "progress"), 4)
    assert mse[3] == common.fmt(metric("progress_mse", "multi"), 4)
    delta = [
        m - s
        for s, m in zip(
            metric("progress_mse", "progress"), metric("progress_mse", "multi"), strict=True
        )
    ]
    assert mse[4] == common.fmt(delta, 4)
    accuracy = rows["accuracy (%)"]
    assert accuracy[1] == "p1"  # action-only exists on p1 alone
    better = metric("action_accuracy", "multi")[0] > metric("action_accuracy", "action")[0]
    verdict = next(ln for ln in text.splitlines() if ln.startswith("- accuracy (%)"))
    assert ("the multi-task model better" in verdict) == better
    assert "one partition, no spread" in verdict
    assert "MPJPE (mm)" not in rows  # no pose-only model was given
    # Per action: the action-only model's recall beside the multi-task model's.
    assert "accuracy (%), action-only" in text
    # Without a multi-task model of the same partition there is nothing to compare.
    assert task_table.main([specs[1]]) == 1
    assert task_table.main([f"shape:p1={tmp_path / 'multi-p1.json'}"]) == 1


def test_the_task_table_compares_a_pose_only_model_per_action_in_a_named_section(
    tmp_path: Path,
) -> None:
    reports = {
        "multi:p1": _report(_frames(400, 1, 0.9), "x", "multi-p1"),
        "pose:p1": _report(_frames(400, 2, 0.4), "x", "pose-p1"),
    }
    doc = tmp_path / "doc.md"
    kept = f"{task_table.BEGIN}\nthe first recipe's table\n{task_table.END}\n"
    doc.write_text(f"{kept}<!-- v12-tasks:begin -->\nold\n<!-- v12-tasks:end -->\n")
    argv = [*_specs(tmp_path, reports), "--write", str(doc), "--section", "v12-tasks"]
    assert task_table.main(argv) == 0
    text = doc.read_text()
    assert text.startswith(kept)  # the default section is left alone
    assert "old" not in text
    rows = {
        ln.split(" | ")[0][2:]: ln.removesuffix(" |").split(" | ")
        for ln in text.splitlines()
        if ln.startswith("| ")
    }
    mpjpe = [reports[k]["metrics"]["mpjpe_mm"] for k in ("pose:p1", "multi:p1")]
    assert rows["MPJPE (mm)"][2:4] == [common.fmt([v], 1) for v in mpjpe]
    assert "accuracy (%)" not in rows  # only the pose task is compared
    # Per action: each model's MPJPE on that action's frames.
    assert "MPJPE (mm), pose-only | MPJPE (mm), multi-task" in text
    squat = [reports[k]["per_action"]["squat"]["mpjpe_mm"] for k in ("pose:p1", "multi:p1")]
    assert rows["squat"][1:3] == [common.fmt([v], 1) for v in squat]


def test_int8_copies_are_scored_on_the_fp32_reports_sessions_and_timed(
    tmp_path: Path, tiny_model_path: Path
) -> None:
    model_dir = tmp_path / "run" / "models"
    model_dir.mkdir(parents=True)
    model = model_dir / "m.onnx"
    shutil.copy2(tiny_model_path, model)
    shutil.copy2(window_graph_for(tiny_model_path), model_dir / "m.window.onnx")
    session = write_session(tmp_path / "s1.ses", 120)
    report = tmp_path / "run" / "eval" / "test.json"
    report.parent.mkdir()
    fp32 = common.run(
        common.scotti_command("eval", session, "--model", model, "--json"), quote=False
    )
    report.write_text(fp32)
    doc = tmp_path / "doc.md"
    doc.write_text(f"{partition_precision.BEGIN}\n{partition_precision.END}\n")
    args = [f"p1={report}", "--steps", "5", "--write", str(doc)]
    assert partition_precision.main(args) == 0

    int8 = model_dir / "int8" / "m.onnx"
    assert int8.is_file()
    assert (model_dir / "int8" / "m.window.onnx").is_file()
    assert ScottiRuntime(int8).window == ScottiRuntime(model).window  # metadata carried over
    scored = json.loads((report.parent / "int8.json").read_text())  # one model: not a list
    assert Path(scored["model"]["path"]).resolve() == int8.resolve()
    assert [s["path"] for s in scored["sessions"]] == [str(session)]
    text = doc.read_text()
    rows = [ln for ln in text.splitlines() if ln.split(" | ")[0] in ("| p1", "| fp32", "| int8")]
    assert [r.split(" | ")[:2] for r in rows[:2]] == [["| p1", "fp32"], ["| p1", "int8"]]
    assert [r.split(" | ")[0] for r in rows[2:]] == ["| fp32", "| int8"]  # the latency rows
    assert rows[2].split(" | ")[7] == "1.00x"  # fp32 against itself
    paired = next(ln for ln in text.splitlines() if ln.startswith("| int8 - fp32 (paired) |"))
    before_after = [json.loads(report.read_text()), scored]
    drop = [
        before_after[1]["metrics"]["action_accuracy"]
        - before_after[0]["metrics"]["action_accuracy"]
    ]
    assert paired.split(" | ")[4] == common.fmt(drop, 3, 100)  # one digit more than the figures
    # A second call reuses the int8 report instead of replaying again.
    before = (report.parent / "int8.json").stat().st_mtime_ns
    assert partition_precision.main(args) == 0
    assert (report.parent / "int8.json").stat().st_mtime_ns == before
    assert partition_precision.main([f"p1={tmp_path / 'missing.json'}"]) == 1


def test_the_ablation_copies_differ_by_their_effects_alone() -> None:
    scenes = effect_ablation.copies(2, 0.02)
    drawn = [e["name"] for e in scenes["all effects"].effects]
    assert len(drawn) >= 2
    assert list(scenes) == ["all effects", "no effects", *(f"without {n}" for n in drawn)]
    assert scenes["no effects"].effects == []
    base = scenes["all effects"].model_dump(exclude={"effects"})
    for name in drawn:
        copy = scenes[f"without {name}"]
        assert [e["name"] for e in copy.effects] == [n for n in drawn if n != name]
        assert copy.model_dump(exclude={"effects"}) == base  # same person, motion, insole
    one = effect_ablation.copies(2, 0.02, (drawn[1],))
    assert list(one) == ["all effects", "no effects", f"without {drawn[1]}"]


def test_the_ablation_scores_each_copy_and_reads_standing_as_squat_from_the_confusion(
    tmp_path: Path, tiny_model_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    every = effect_ablation.copies(2, 0.02)
    two = {k: every[k] for k in ("all effects", "no effects")}
    monkeypatch.setattr(effect_ablation, "copies", lambda subject, minutes, leave_out: two)
    doc = tmp_path / "doc.md"
    doc.write_text(f"{effect_ablation.BEGIN}\n{effect_ablation.END}\n")
    args = ["--subject", "2", "--model", str(tiny_model_path), "--out", str(tmp_path / "abl")]
    assert effect_ablation.main([*args, "--every", "4", "--write", str(doc)]) == 0
    assert sorted(p.name for p in (tmp_path / "abl").glob("*.ses")) == [
        "all-effects.ses",
        "no-effects.ses",
    ]
    rows = [ln.split(" | ") for ln in doc.read_text().splitlines() if ln.startswith("| all")]
    (first,) = (tmp_path / "abl").glob("all-effects.*.every4.json")
    report = json.loads(first.read_text())
    actions = report["confusion"]["actions"]
    standing = report["confusion"]["matrix"][actions.index("standing")]
    share = standing[actions.index("squat")] / max(1, sum(standing))
    assert rows[0][3] == f"{100 * share:.1f}"
    assert report["every"] == 4
    # Another model gets reports of its own: the first model's stay as they were.
    before = first.read_bytes()
    standing = always_standing(tiny_model_path, tmp_path / "standing.onnx")
    always_standing(window_graph_for(tiny_model_path), window_graph_for(standing))
    other = ["--model", str(standing), "--out", str(tmp_path / "abl"), "--every", "4"]
    assert effect_ablation.main(["--subject", "2", *other]) == 0
    assert len(list((tmp_path / "abl").glob("all-effects.*.every4.json"))) == 2
    assert first.read_bytes() == before
    assert effect_ablation.main(["--subject", "2", "--model", str(tmp_path / "none.onnx")]) == 1


def test_an_arch_run_trains_its_config_and_scores_through_its_window(tmp_path: Path) -> None:
    parser = partition_runs.build_parser()
    wide, short = (
        partition_runs.plan(parser.parse_args(["p3", "--arch", name]))[0]
        for name in ("E256-L2-T40", "E128-L2-T20")
    )
    assert wide.run_dir.name == "v9-p3-E256-L2-T40"
    assert short.run_dir.name == "v9-p3-E128-L2-T20"
    assert (wide.window, short.window) == (40, 20)
    args = parser.parse_args(["p3", "--arch", "E256-L2-T40"])
    partition_runs.plan(args)
    assert json.loads(args.config) == configs.CONFIGS["E256-L2-T40"]
    assert args.lr == configs.LEARNING_RATE[256]  # the width's, unless --lr says otherwise
    args = parser.parse_args(["p3", "--arch", "E256-L2-T40", "--lr", "0.002"])
    partition_runs.plan(args)
    assert args.lr == 0.002
    plain = parser.parse_args(["p3"])
    (job,) = partition_runs.plan(plain)
    assert (plain.config, plain.lr, job.window, job.run_dir.name) == ("small", 1e-3, 40, "v9-p3")
    (augmented,) = partition_runs.plan(parser.parse_args(["p2", "--max-crosstalk", "0.03"]))
    assert augmented.run_dir.name == "v9-p2-xt0.03"
    # The contract's window goes straight to scotti; another one through any_window.py.
    assert partition_runs.verb(40, "eval", "x.ses")[1:3] == ["-m", "scotti.cli.main"]
    assert partition_runs.verb(20, "eval", "x.ses")[1:] == [
        str(EXPERIMENTS / "any_window.py"),
        "20",
        "eval",
        "x.ses",
    ]


def _claiming(report: dict[str, Any], model: Path, embed_dim: int, window: int) -> dict[str, Any]:
    return {**report, "model": {"path": str(model), "embed_dim": embed_dim, "window": window}}


def test_the_arch_table_compares_each_config_with_the_baseline_on_shared_partitions(
    tmp_path: Path, tiny_model_path: Path
) -> None:
    reports = {
        key: _claiming(
            _report(_frames(400, seed, quality), "x", key.replace(":", "-")),
            tiny_model_path,
            configs.CONFIGS[key.split(":")[0]]["embed_dim"],
            configs.window_of(key.split(":")[0]),
        )
        for seed, (key, quality) in enumerate(
            [
                ("E128-L2-T40:p1", 0.8),
                ("E128-L2-T40:p3", 0.7),
                ("E128-L2-T20:p3", 0.6),
                ("E256-L2-T40:p2", 0.9),
            ]
        )
    }
    specs = _specs(tmp_path, reports)
    doc = tmp_path / "doc.md"
    doc.write_text("head\n<!-- archs:begin -->\nold\n<!-- archs:end -->\n")
    assert arch_table.main([*specs, "--steps", "3", "--write", str(doc)]) == 0
    text = doc.read_text()
    assert text.startswith("head\n")
    assert "old" not in text
    rows = [ln.removesuffix(" |").split(" | ") for ln in text.splitlines() if ln.startswith("| E")]
    first = {r[0][2:]: r for r in rows[:3]}  # accuracy and cost, one row per config
    assert list(first) == ["E128-L2-T40", "E128-L2-T20", "E256-L2-T40"]
    assert first["E128-L2-T40"][1] == "p1, p3"
    mse = [reports[f"E128-L2-T40:{p}"]["metrics"]["progress_mse"] for p in ("p1", "p3")]
    assert first["E128-L2-T40"][5] == common.fmt(mse, 4)
    assert first["E128-L2-T40"][-1] == "1.00x"  # the baseline against itself
    paired = rows[3:]
    # Only T20 shares a partition with the baseline; E256 (p2 alone) has nothing to pair.
    assert [r[0][2:] for r in paired] == ["E128-L2-T20"]
    delta = [
        reports["E128-L2-T20:p3"]["metrics"]["action_accuracy"]
        - reports["E128-L2-T40:p3"]["metrics"]["action_accuracy"]
    ]
    assert paired[0][1] == "p3"
    assert paired[0][4] == common.fmt(delta, 2, 100)
    # A report whose model is not the config it is filed under is refused.
    wrong = _write(
        tmp_path / "wrong.json", _claiming(reports["E128-L2-T20:p3"], tiny_model_path, 32, 40)
    )
    assert arch_table.main([f"E128-L2-T20:p3={wrong}", "--steps", "3"]) == 1
    assert arch_table.main([f"E999:p3={specs[0].split('=')[1]}"]) == 1


def test_the_arch_table_picks_a_model_of_a_report_and_writes_a_named_section(
    tmp_path: Path, tiny_model_path: Path
) -> None:
    def scored(seed: int, quality: float, path: str) -> dict[str, Any]:
        report = _claiming(
            _report(_frames(400, seed, quality), "x", "p1"), tiny_model_path, 128, 40
        )
        return {**report, "model": {**report["model"], "path": path}}

    tuned, shipped = scored(0, 0.9, "runs/tuned.onnx"), scored(1, 0.5, str(tiny_model_path))
    both = tmp_path / "both.json"
    both.write_text(json.dumps([tuned, shipped]))  # as head_finetune.py's eval writes it
    doc = tmp_path / "doc.md"
    doc.write_text(
        "<!-- archs:begin -->\nkept\n<!-- archs:end -->\n<!-- xt:begin -->\n<!-- xt:end -->\n"
    )
    spec = f"E128-L2-T40:p1={both}#{tiny_model_path.name}"
    assert arch_table.main([spec, "--steps", "3", "--write", str(doc), "--section", "xt"]) == 0
    text = doc.read_text()
    assert "kept" in text  # the other section is left alone
    (row,) = [ln.split(" | ") for ln in text.splitlines() if ln.startswith("| E128-L2-T40 | p1")]
    assert row[5] == common.fmt([shipped["metrics"]["progress_mse"]], 4)  # not the first model's
    assert arch_table.main([f"E128-L2-T40:p1={both}#nothing-like-it", "--steps", "3"]) == 1


def test_the_recipe_table_pairs_recipes_person_by_person_on_the_same_sessions(
    tmp_path: Path,
) -> None:
    def scored(seed: int, quality: float, partition: str) -> dict[str, Any]:
        report = _report(_frames(400, seed, quality), "x", f"{partition}-{seed}")
        report["sessions"] = [
            {**report["sessions"][0], "subject": f"{partition}-s", "path": f"/d/{partition}.ses"}
        ]
        return report

    reports = {
        "plain:p1": scored(1, 0.6, "p1"),
        "crosstalk:p1": scored(2, 0.9, "p1"),
        "plain:p2": scored(3, 0.7, "p2"),
        "crosstalk:p2": scored(4, 0.8, "p2"),
    }
    specs = _specs(tmp_path, reports)
    doc = tmp_path / "doc.md"
    doc.write_text("<!-- recipes:begin -->\n<!-- recipes:end -->\n")
    assert recipe_table.main([*specs, "--write", str(doc)]) == 0
    rows = [ln.removesuffix(" |").split(" | ") for ln in doc.read_text().splitlines()]
    accuracy = next(r for r in rows if r[0] == "| accuracy (%)")
    assert accuracy[1:3] == ["crosstalk", "p1, p2"]
    delta = [
        reports[f"crosstalk:{p}"]["metrics"]["action_accuracy"]
        - reports[f"plain:{p}"]["metrics"]["action_accuracy"]
        for p in ("p1", "p2")
    ]
    assert accuracy[5] == common.fmt(delta, 2, 100)
    person = next(r for r in rows if r[0] == "| p2-s (p2)")
    assert person[4:6] == [
        common.fmt([reports["plain:p2"]["sessions"][0]["metrics"]["action_accuracy"]], 2, 100),
        common.fmt([reports["crosstalk:p2"]["sessions"][0]["metrics"]["action_accuracy"]], 2, 100),
    ]
    # Scored on other session files: no paired comparison.
    moved = {
        **reports["crosstalk:p2"],
        "sessions": [{**reports["crosstalk:p2"]["sessions"][0], "path": "/d/x.ses"}],
    }
    other = _write(tmp_path / "moved.json", moved)
    assert recipe_table.main([specs[2], f"crosstalk:p2={other}"]) == 1
    assert recipe_table.main([specs[0]]) == 1  # nothing to compare with


def test_the_recipe_table_compares_two_models_of_one_replay_in_a_named_section(
    tmp_path: Path,
) -> None:
    def scored(seed: int, quality: float, name: str) -> dict[str, Any]:
        report = _report(_frames(400, seed, quality), "multi", name)
        report["sessions"] = [{**report["sessions"][0], "path": "/d/s.ses"}]  # the same replay
        return report

    shipped, trained_on = scored(5, 0.7, "scotti-default"), scored(6, 0.9, "v10-p1")
    both = _write(tmp_path / "both.json", shipped)
    Path(both).write_text(
        json.dumps([trained_on, {**trained_on, "model": {"path": "x/export-fit.onnx"}}, shipped])
    )
    doc = tmp_path / "doc.md"
    kept = "<!-- recipes:begin -->\nthe crosstalk table\n<!-- recipes:end -->\n"
    doc.write_text(kept + "<!-- warm:begin -->\n<!-- warm:end -->\n")
    specs = [f"shipped:p1={both}#scotti-default", f"warm:p1={both}#v10-p1"]
    assert recipe_table.main([*specs, "--write", str(doc), "--section", "warm"]) == 0
    text = doc.read_text()
    assert text.startswith(kept)  # the other section is left as it was
    rows = [ln.removesuffix(" |").split(" | ") for ln in text.splitlines()]
    accuracy = next(r for r in rows if r[0] == "| accuracy (%)")
    delta = trained_on["metrics"]["action_accuracy"] - shipped["metrics"]["action_accuracy"]
    assert accuracy[1] == "warm"
    assert accuracy[5] == common.fmt([delta], 2, 100)
    assert recipe_table.main([f"shipped:p1={both}#nothing-like-it", specs[1]]) == 1


def test_a_run_from_a_shipped_graph_passes_init_not_config_on_every_call(tmp_path: Path) -> None:
    import argparse
    import dataclasses

    from scotti.export import train_args

    parser = partition_runs.build_parser()
    graph = tmp_path / "shipped.onnx"
    args = parser.parse_args(["p1", "--init", str(graph), "--lr", "3e-4", "--group", "v10"])
    (job,) = partition_runs.plan(args)
    assert job.init == graph
    assert job.run_dir.name == "v10-p1"
    job = dataclasses.replace(job, run_dir=tmp_path / "run")
    train = argparse.ArgumentParser()
    train_args.add_arguments(train)
    corpus = tmp_path / "corpus"
    (corpus / "realistic").mkdir(parents=True)
    for subject in job.train:
        (corpus / "realistic" / f"{subject}.ses").write_bytes(b"")

    def parsed(command: list[str]) -> argparse.Namespace:
        assert command[1:4] == ["-m", "scotti.cli.main", "train"]
        return train.parse_args(command[4:])

    first = parsed(job.train_command(corpus, args))
    # scotti train takes the size from --init and refuses --config beside it.
    assert (first.init, first.config, first.resume, first.lr) == (graph, None, False, 3e-4)
    job.run_dir.mkdir()
    (job.run_dir / "last.pt").write_bytes(b"")
    again = parsed(job.train_command(corpus, args))
    assert (again.init, again.config, again.resume) == (graph, None, True)
    scratch = partition_runs.plan(parser.parse_args(["p1"]))[0]
    assert scratch.init is None
    assert parsed(scratch.train_command(corpus, args)).config == "small"


def test_the_drivers_pass_force_where_they_remake_and_resume_where_they_go_on(
    tmp_path: Path,
) -> None:
    import argparse
    import dataclasses

    import corpus
    import training
    from scotti.export import export_cli, train_args

    def parser_of(add_arguments: Any) -> argparse.ArgumentParser:
        parser = argparse.ArgumentParser()
        add_arguments(parser)
        return parser

    export, train = parser_of(export_cli.add_arguments), parser_of(train_args.add_arguments)
    args = partition_runs.build_parser().parse_args(["p1"])
    (job,) = partition_runs.plan(args)
    job = dataclasses.replace(job, run_dir=tmp_path / "run")
    data = tmp_path / "corpus"
    (data / "realistic").mkdir(parents=True)
    for subject in job.train:
        (data / "realistic" / f"{subject}.ses").write_bytes(b"")
    # Scoring again exports the run's best.pt over the graphs a scoring before left.
    command = partition_runs.verb(job.window, *partition_runs.export_command(job, data, data))
    assert command[1:4] == ["-m", "scotti.cli.main", "export"]
    scored = export.parse_args(command[4:])
    assert scored.force
    assert scored.output == job.run_dir / "models" / "scotti-ship.onnx"
    assert scored.checkpoint == job.run_dir / "best.pt"
    # Training goes on from last.pt, never starts over on its own.
    fresh = train.parse_args(job.train_command(data, args)[4:])
    assert (fresh.resume, fresh.force) == (False, False)
    job.run_dir.mkdir()
    (job.run_dir / "last.pt").write_bytes(b"")
    again = train.parse_args(job.train_command(data, args)[4:])
    assert (again.resume, again.force) == (True, False)
    # experiments/training.py: the same, and a stale export replaced.
    spec = training.RunSpec(job.run_dir, common.Partition("p1", job.train, job.test, data), "tiny")
    resumed = train.parse_args(spec.train_args(epochs=1, stride=2, minutes=1, resume=True))
    assert (resumed.resume, resumed.force) == (True, False)
    onnx = tmp_path / "models" / "x.onnx"
    exported = export.parse_args(training.export_command(job.run_dir, onnx, int8=True)[4:])
    assert (exported.force, exported.int8, exported.output) == (True, True, onnx)
    # A corpus without its manifest was cut short: rendered again over what it left.
    render = corpus.render_command(tmp_path / "c", "none", corpus.build_parser().parse_args([]))
    assert render[3:7] == ["sim", "corpus", "-o", str(tmp_path / "c")]
    assert "--force" in render


def test_a_bf16_run_has_its_own_directory_and_asks_scotti_train_for_bf16(tmp_path: Path) -> None:
    import argparse
    import dataclasses

    from scotti.export import train_args

    parser = partition_runs.build_parser()
    recipe = "--max-crosstalk 0.03 --more more --precision bf16 --group v12ema"
    args = parser.parse_args(["p1", "--variant", "pose", *recipe.split()])
    (job,) = partition_runs.plan(args)
    assert job.run_dir.name == "v12ema-p1-pose-xt0.03-more-bf16"
    plain_args = parser.parse_args(["p1", "--group", "v12ema"])
    (plain,) = partition_runs.plan(plain_args)
    assert plain.run_dir.name == "v12ema-p1"  # fp32 runs keep the names they had
    corpus = tmp_path / "corpus"
    for folder in ("realistic", "more"):
        (corpus / folder).mkdir(parents=True)
    for subject in job.train:
        (corpus / "realistic" / f"{subject}.ses").write_bytes(b"")
    (corpus / "more" / "subject-033.ses").write_bytes(b"")
    job = dataclasses.replace(job, run_dir=tmp_path / "run")
    train = argparse.ArgumentParser()
    train_args.add_arguments(train)
    command = job.train_command(corpus, args)
    assert command[1:4] == ["-m", "scotti.cli.main", "train"]
    parsed = train.parse_args(command[4:])
    assert (parsed.precision, parsed.loss_weights) == ("bf16", "0.01,0,0")
    fp32 = train.parse_args(plain.train_command(corpus, plain_args)[4:])
    assert fp32.precision == "fp32"


def test_model_paths_named_from_another_folder_reach_scotti_as_absolute_paths(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The scotti commands run in the repository root: a path relative to the caller's
    # folder (say ../models/x.onnx from experiments/) must not be read from there.
    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "shipped.onnx").write_bytes(b"graph")
    caller = tmp_path / "experiments"
    caller.mkdir()
    monkeypatch.chdir(caller)
    parser = partition_runs.build_parser()
    args = parser.parse_args(
        [
            "p1",
            "--beside", "p1=../models/shipped.onnx",
            "--init", "../models/shipped.onnx",
            "--corpus", "../corpus",
            "--cache", "../cache",
        ]
    )  # fmt: skip
    (job,) = partition_runs.plan(args)
    assert args.corpus == tmp_path / "experiments" / ".." / "corpus"
    assert args.cache == tmp_path / "experiments" / ".." / "cache"
    assert job.beside is not None
    assert job.init is not None
    assert job.beside.is_absolute()
    assert job.init.is_absolute()
    assert job.beside.read_bytes() == job.init.read_bytes() == b"graph"
    assert job.beside.resolve() == (tmp_path / "models" / "shipped.onnx").resolve()


def test_a_streaming_run_asks_scotti_train_for_the_form_in_its_own_directory(
    tmp_path: Path,
) -> None:
    import argparse
    import dataclasses

    from scotti.export import train_args
    from scotti.export.model import ARCHES

    assert partition_runs.FORMS == ARCHES  # the choices are scotti train's
    parser = partition_runs.build_parser()
    train = argparse.ArgumentParser()
    train_args.add_arguments(train)
    corpus = tmp_path / "corpus"
    (corpus / "realistic").mkdir(parents=True)

    def parsed(argv: list[str]) -> tuple[partition_runs.PartitionRun, argparse.Namespace]:
        args = parser.parse_args(argv)
        (job,) = partition_runs.plan(args)
        for subject in job.train:
            (corpus / "realistic" / f"{subject}.ses").write_bytes(b"")
        moved = dataclasses.replace(job, run_dir=tmp_path / job.run_dir.name)
        command = moved.train_command(corpus, args)
        assert command[1:4] == ["-m", "scotti.cli.main", "train"]
        return job, train.parse_args(command[4:])

    job, streaming = parsed(["p1", "--form", "streaming", "--group", "v14"])
    assert job.run_dir.name == "v14-p1-streaming"
    assert (streaming.arch, streaming.config, job.window) == ("streaming", "small", 40)
    # --arch picks the size from experiments/configs.py, --form the form: both reach train.
    job, sized = parsed(["p3", "--arch", "E128-L2-T20", "--form", "streaming"])
    assert job.run_dir.name == "v9-p3-E128-L2-T20-streaming"
    assert (sized.arch, json.loads(sized.config), job.window) == (
        "streaming",
        configs.CONFIGS["E128-L2-T20"],
        20,
    )
    # The paper form (the default) keeps its directory and its command: no --arch.
    job, paper = parsed(["p1", "--group", "v14"])
    assert (job.run_dir.name, paper.arch) == ("v14-p1", None)
    job, named = parsed(["p1", "--group", "v14", "--form", "paper"])
    assert (job.run_dir.name, named.arch) == ("v14-p1", None)
    # Scoring exports the run's own best.pt (scotti export routes a streaming checkpoint to
    # the key/value graphs itself: tests/test_calibrate_streaming_native.py) into the run.
    job, _ = parsed(["p1", "--form", "streaming"])
    export = partition_runs.export_command(job, corpus, corpus)
    model = job.run_dir / "models" / "scotti-ship.onnx"
    assert export[:5] == ["export", job.run_dir / "best.pt", "-o", model, "--calibrate"]
