"""The coverage grid (experiments/coverage*.py): it sweeps every field a scene may set
over the whole range the schema accepts, and a tiny run scores a cell with every
metric and reuses its checkpoint.

The schema is read here from pydantic's JSON schema, apart from the grid's own
reading, so a new field or a changed range of sim/scene.py, the insole or an
effect fails the first test until the grid sweeps it or declares why not.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from scotti.models.contract import ACTIONS
from scotti.sim.effects.registry import EFFECT_MODELS
from scotti.sim.scene import Scene

from tests.support.fixtures_models import TINY_STEP
from tests.test_experiments_docs import EXPERIMENTS

sys.path.insert(0, str(EXPERIMENTS))

import coverage
import coverage_grid
from common import write_card_section
from coverage_doc import card_section
from coverage_doc_rows import Row, Summary
from coverage_doc_tables import published_wrong
from coverage_envelope import envelope_table, envelopes
from coverage_refine import midpoint, refined, refinements
from coverage_score import Counts, detector

SCENES = Path(__file__).resolve().parent.parent / "sim" / "scenes"


def _properties(schema: dict[str, Any], node: dict[str, Any], prefix: str) -> Iterator[Any]:
    """(path, property schema, default) of every leaf field, following $refs and arrays."""
    defs = schema.get("$defs", {})
    for name, prop in node.get("properties", {}).items():
        path = prefix + name
        target = _target(prop, defs)
        if target is not None and path in ("subject", "script", "insole"):
            yield from _properties(schema, target, path + ".")
        else:
            yield path, prop, prop.get("default")


def _target(prop: dict[str, Any], defs: dict[str, Any]) -> dict[str, Any] | None:
    """The model a property holds (directly, in a list, or optional), if any."""
    for candidate in (prop, prop.get("items", {}), *prop.get("anyOf", [])):
        ref = candidate.get("$ref")
        if ref:
            return dict(defs[ref.rsplit("/", 1)[-1]])
    return None


def _bounds(prop: dict[str, Any]) -> tuple[Any, Any, Any, Any]:
    """(minimum, exclusive minimum, maximum, exclusive maximum) of a number, else Nones."""
    for variant in (prop, *prop.get("anyOf", [])):
        if variant.get("type") in ("number", "integer"):
            return (
                variant.get("minimum"),
                variant.get("exclusiveMinimum"),
                variant.get("maximum"),
                variant.get("exclusiveMaximum"),
            )
    return None, None, None, None


def _choices(prop: dict[str, Any]) -> list[Any] | None:
    for variant in (prop, *prop.get("anyOf", [])):
        if "enum" in variant:
            return list(variant["enum"])
        if variant.get("type") == "boolean":
            return [False, True]
    return None


def _schema_leaves() -> list[tuple[str, dict[str, Any], Any]]:
    scene = Scene.model_json_schema()
    leaves = list(_properties(scene, scene, ""))
    for name, model in EFFECT_MODELS.items():
        schema = model.model_json_schema()
        leaves += list(_properties(schema, schema, f"effects.{name}."))
    return leaves


def _near(value: Any, bound: float, span: float) -> bool:
    return isinstance(value, int | float) and abs(value - bound) <= 1e-3 * span


def test_every_scene_field_is_swept_over_its_whole_range_or_declared_with_a_reason() -> None:
    swept = {p.path: p for p in coverage_grid.parameters()}
    problems = []
    leaves = _schema_leaves()
    assert {"subject.height_m", "script.tempo", "insole.gain_sigma"} <= {p for p, _, _ in leaves}
    for path, prop, default in leaves:
        if path in coverage_grid.SKIPPED:
            assert coverage_grid.SKIPPED[path].strip(), path
            continue
        if path not in swept:
            problems.append(f"{path}: not swept and not declared skipped")
            continue
        values = {*swept[path].values, default}  # the default is the baseline's cell
        if path in coverage_grid.NOT_RANGE:
            why, declared = coverage_grid.NOT_RANGE[path]
            assert why.strip()
            assert set(declared) <= values, path
            continue
        if path == "effects":
            missing = {"realistic", *EFFECT_MODELS} - values
            problems += [f"effects: {m} not swept" for m in sorted(missing)]
            continue
        choices = _choices(prop)
        if choices is not None:
            problems += [f"{path}: {c!r} not swept" for c in choices if c not in values]
            continue
        low, low_open, high, high_open = _bounds(prop)
        if (low is None and low_open is None) or (high is None and high_open is None):
            problems.append(f"{path}: no range in the schema and no declared values")
            continue
        lo = low if low is not None else low_open
        hi = high if high is not None else high_open
        span = hi - lo
        if not any(_near(v, lo, span) and (low_open is None or v > lo) for v in values):
            problems.append(
                f"{path}: the schema's minimum {lo} is not swept ({sorted(values, key=str)})"
            )
        if not any(_near(v, hi, span) and (high_open is None or v < hi) for v in values):
            problems.append(
                f"{path}: the schema's maximum {hi} is not swept ({sorted(values, key=str)})"
            )
    assert not problems, "\n".join(problems)


def test_a_field_without_a_range_must_be_declared() -> None:
    field = coverage_grid.SchemaField("subject.new_trait", "number", low=0.0)
    with pytest.raises(coverage_grid.GridError, match=r"subject\.new_trait has no range"):
        coverage_grid.parameters([field])


def test_every_cell_of_the_grid_is_a_scene_the_schema_accepts() -> None:
    person = coverage_grid.people(1)[0]
    grid = coverage_grid.cells()
    assert len({(c.action, c.path, str(c.value)) for c in grid}) == len(grid)
    assert {c.action for c in grid} == set(ACTIONS)
    for cell in grid:
        raw = cell.scene(person, 10.0)
        scene = Scene.model_validate(raw)
        scene.check_effects()
        if cell.path is not None and cell.path.startswith("subject."):
            assert getattr(scene.subject, cell.path.split(".")[1]) == cell.value


def test_the_flag_as_detector_counts_precision_and_recall_of_wrong_predictions() -> None:
    a = Counts(predictions=100, wrong=20, unfamiliar=10, flagged=15, wrong_unfamiliar=5,
               wrong_flagged=12, wrong_unflagged=8, wrong_unflagged_confident=3)  # fmt: skip
    b = Counts(predictions=100, wrong=0, unfamiliar=10, flagged=10)
    both = a + b
    assert both.predictions == 200
    assert both.share("wrong_unflagged") == pytest.approx(0.04)
    unfamiliar = detector(both, "unfamiliar")
    assert unfamiliar.precision == pytest.approx(5 / 20)
    assert unfamiliar.recall == pytest.approx(5 / 20)
    assert unfamiliar.base_rate == pytest.approx(0.1)
    anyflag = detector(both, "flagged")
    assert anyflag.precision == pytest.approx(12 / 25)
    assert anyflag.recall == pytest.approx(12 / 20)
    assert detector(Counts(), "unfamiliar").precision is None


def _row(label: str, predictions: int, wrong_unflagged: int, named: dict[str, int]) -> Row:
    counts = Counts(predictions=predictions, wrong=wrong_unflagged, wrong_unflagged=wrong_unflagged)
    return Row({"action": "side_walking", "path": "script.step_length_m", "label": label,
                "counts": vars(counts), "metrics": {"action_accuracy": 0.5},
                "wrong_unflagged_as": named})  # fmt: skip


def test_cells_publishing_wrong_answers_are_listed_with_what_they_named() -> None:
    over = _row("side_walking: script.step_length_m = 0.00015", 200, 150,
                {"standing": 10, "in_place_walking": 140})  # fmt: skip
    under = _row("side_walking: script.step_length_m = 0.6", 200, 10, {"walking": 10})
    assert over.read_as() == "in_place_walking 70.0 %, standing 5.0 %"
    assert over.read_as(most=1) == "in_place_walking 70.0 %"
    lines = published_wrong([under, over])
    rows = [line for line in lines if line.startswith("| side_walking")]
    assert len(rows) == 1  # 5 % of its predictions is not over the goal
    assert "script.step_length_m = 0.00015" in rows[0]
    assert "in_place_walking 70.0 %" in rows[0]
    assert _row("x: y = 1", 200, 0, {}).read_as() == "-"  # an older checkpoint: none counted
    assert published_wrong([under])[0].startswith("No cell publishes more than")


def _cell(action: str, label: str, accuracy: float = 0.99, wrong_unflagged: int = 0,
          unchanged: bool = False) -> Row:  # fmt: skip
    path = None if label == "baseline" else label.split(" = ")[0]
    if unchanged:
        return Row({"action": action, "path": path, "label": label, "unchanged": True})
    counts = Counts(predictions=100, wrong=wrong_unflagged, wrong_unflagged=wrong_unflagged)
    return Row({"action": action, "path": path, "label": label, "counts": vars(counts),
                "metrics": {"action_accuracy": accuracy, "app": 0.9}})  # fmt: skip


def _summary(*params: coverage_grid.Parameter) -> Summary:
    return Summary(command="", people=1, seconds=5.0, model="m", model_sha="0" * 12,
                   commit="c", date="d", actions=("squat", "walking"), parameters=params,
                   cpu_minutes=0.0, wall_minutes=0.0, jobs_left=0)  # fmt: skip


def test_a_fields_envelope_runs_from_its_default_to_the_first_cell_that_misses() -> None:
    tempo = coverage_grid.Parameter("script.tempo", (0.3, 0.975, 1.65, 2.33, 3.0), 1.0)
    height = coverage_grid.Parameter("subject.height_m", (1.2, 1.45, 1.7, 1.95, 2.2))
    rows = [_cell(a, "baseline") for a in ("squat", "walking")]
    for v in tempo.values:
        label = f"script.tempo = {v:g}"
        rows.append(_cell("squat", label, accuracy=0.5 if v == 0.3 else 0.99))
        rows.append(_cell("walking", label, wrong_unflagged=10 if v > 2 else 0))
    for v in height.values:
        label = f"subject.height_m = {v:g}"
        bad = v in (1.2, 1.95)  # 1.95 misses: the longest run is 1.45 to 1.7, not 2.2 alone
        rows.append(_cell("squat", label, accuracy=0.8 if bad else 0.99))
        rows.append(_cell("walking", label, unchanged=True))  # the baseline's motion
    found = {e.path: e for e in envelopes(_summary(tempo, height), rows)}
    t = found["script.tempo"]
    assert t.run == (0.975, 1.65)
    assert t.below is not None
    assert t.below.value == 0.3
    assert set(t.below.misses) == {"squat"}
    assert t.above is not None
    assert t.above.value == 2.33
    assert t.above.misses == {"walking": "wrong and unflagged 10.0 %"}
    h = found["subject.height_m"]
    assert h.run == (1.45, 1.7)
    assert h.below is not None
    assert h.below.value == 1.2
    text = "\n".join(envelope_table(_summary(tempo, height), rows))
    assert "| script.tempo | 0.3 to 3 | 0.975 to 1.65 | 0.3: squat (accuracy 50.0 %) |" in text
    flips = coverage_grid.Parameter("effects.line_corruption.flip_rate_per_byte", (0.0, 0.1), 1e-5)
    silent = Row({"action": "squat", "path": flips.path, "label": f"{flips.path} = 0.1",
                  "counts": vars(Counts()), "metrics": {}})  # fmt: skip
    more = [_cell(a, "effects = line_corruption") for a in ("squat", "walking")]
    more += [_cell(a, f"{flips.path} = 0") for a in ("squat", "walking")]
    more += [silent, Row(silent.result | {"action": "walking"})]
    f = envelopes(_summary(flips), more)[0]
    assert f.run == (0.0, 1e-5)  # from the effect at its defaults, down to 0
    assert (f.low, f.high) == (0.0, 0.1)
    assert "| 0 to 1e-05 | - | 0.1: 2 actions (no prediction) |" in "\n".join(
        envelope_table(_summary(flips), more)
    )
    added = refinements(_summary(tempo, height), rows)
    assert set(added) == {"script.tempo", "subject.height_m"}
    low, high = added["script.tempo"]
    assert low == pytest.approx(0.6375, abs=0.001)  # halfway from 0.975 down to 0.3
    assert high == pytest.approx(1.99)  # from 1.65 up to 2.33
    assert added["subject.height_m"] == (pytest.approx(1.32, abs=0.01), 1.82)
    more = refined((tempo, height), added)
    assert more[0].values == (0.3, low, 0.975, 1.65, high, 2.33, 3.0)
    assert more[0].default == 1.0
    rows[0] = _cell("squat", "baseline", accuracy=0.5)  # the default itself misses
    again = {e.path: e for e in envelopes(_summary(tempo), rows)}
    assert again["script.tempo"].run is None


def test_a_refined_value_halves_the_span_where_a_field_stops_holding() -> None:
    assert midpoint(1.0, 1.65, integer=False) == pytest.approx(1.325, abs=0.006)
    assert midpoint(500.0, 10.0, integer=False) == pytest.approx(70.7)  # 50 x apart: by ratio
    assert midpoint(0.0, -500.0, integer=False) == -250.0
    assert midpoint(8, 16, integer=True) == 12
    assert midpoint(30, 31, integer=True) is None  # nothing left between
    assert midpoint(1.0, 1.001, integer=False) is None  # not at three significant digits


def test_the_card_quotes_the_headline_the_goals_and_how_many_fields_hold(
    tmp_path: Path,
) -> None:
    tempo = coverage_grid.Parameter("script.tempo", (0.3, 3.0), 1.0)
    rows = [_cell(a, "baseline") for a in ("squat", "walking")]
    rows += [_cell("squat", "script.tempo = 0.3", accuracy=0.4)]
    rows += [_cell("walking", "script.tempo = 0.3"), *(_cell(a, "script.tempo = 3") for a in
             ("squat", "walking"))]  # fmt: skip
    text = card_section(_summary(tempo), rows, [])
    assert text.startswith("## Outside its corpus")
    assert "**Worst cell: squat with script.tempo = 0.3: accuracy 40.0 %" in text
    assert "| worst cell accuracy >= 90 % | 40.0 % (squat, script.tempo = 0.3)" in text
    assert "whole swept range of 0 of the 1 numeric fields" in text
    card = tmp_path / "m.card.md"
    card.write_text("# Model card: m\n\n## Files\n- m.onnx\n")
    write_card_section(card, text, "coverage")
    write_card_section(card, "## Real recordings\n", "real-data")
    write_card_section(card, text.replace("40.0 %", "41.0 %"), "coverage")  # replaced in place
    written = card.read_text()
    assert written.startswith("# Model card: m\n\n## Files\n- m.onnx\n\n<!-- coverage:begin -->")
    assert written.count("<!-- coverage:begin -->") == 1
    assert "41.0 %" in written
    assert "40.0 %" not in written
    assert written.index("coverage:end") < written.index("## Real recordings")


@pytest.mark.slow
def test_a_tiny_run_scores_every_metric_and_reuses_its_checkpoints(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    scenes = tmp_path / "scenes"
    scenes.mkdir()
    text = (SCENES / "squat.toml").read_text().replace("reps = 6", "reps = 2")
    (scenes / "squat.toml").write_text(text)
    doc = tmp_path / "coverage.md"
    cache = tmp_path / "cache"
    argv = ["--action", "squat", "--param", "insole.model", "--people", "1", "--seconds", "5",
            "--model", str(TINY_STEP), "--cache", str(cache), "--write", str(doc),
            "--scenes", str(scenes), "--refine", "2"]  # fmt: skip
    assert coverage.main(argv) == 0
    first = capsys.readouterr().out
    assert "3 cells scored, 0 unchanged, 0 from the cache, 0 left" in first
    checkpoints = sorted((cache / "cells").glob("*.json"))
    assert len(checkpoints) == 3  # the baseline, insole.model = ideal, the scene file
    results = [json.loads(p.read_text()) for p in checkpoints]
    cell = next(r for r in results if r.get("path") == "insole.model")
    assert cell["action"] == "squat"
    assert cell["value"] == "ideal"
    m = cell["metrics"]
    for name in ("action_accuracy", "app", "mpjpe_mm", "progress_mse"):
        assert isinstance(m[name], float), name
    assert 0.0 <= m["action_accuracy"] <= 1.0
    counts = Counts.of(cell["counts"])
    assert counts.predictions == m["frames_action"] > 0
    for name in ("unloaded", "out_of_range", "unfamiliar", "wrong_unflagged",
                 "wrong_unflagged_confident"):  # fmt: skip
        share = counts.share(name)
        assert share is not None
        assert 0.0 <= share <= 1.0
    assert counts.wrong == round((1 - m["action_accuracy"]) * counts.predictions)
    assert counts.wrong == counts.wrong_flagged + counts.wrong_unflagged
    named = cell["wrong_unflagged_as"]
    assert sum(named.values()) == counts.wrong_unflagged
    assert set(named) <= set(ACTIONS) - {"squat"}  # a wrong answer names another action
    assert not list((cache / "sessions").rglob("*.ses"))  # sessions go once scored
    text = doc.read_text()
    row = next(line for line in text.splitlines() if line.startswith("| insole.model = ideal |"))
    assert f"{100 * m['action_accuracy']:.1f}" in row
    assert "**Worst cell: squat with" in text
    assert "squat.toml`" in text
    assert "precision (flagged that are wrong)" in text
    assert "## Wrong answers that went out, and what they named" in text
    assert "| insole.model" not in text.split("## Where each field holds")[1].split("##")[0]
    stamps = [p.stat().st_mtime_ns for p in checkpoints]

    assert coverage.main(argv) == 0
    second = capsys.readouterr().out
    assert "0 cells scored, 0 unchanged, 3 from the cache, 0 left" in second
    assert [p.stat().st_mtime_ns for p in checkpoints] == stamps
    assert doc.read_text().split("## Goals")[1] == text.split("## Goals")[1]


@pytest.mark.parametrize(
    ("extra", "shipped_doc"),
    [
        ([], True),  # the shipped model over the whole grid: its table in docs
        (["--model", "runs/candidate.onnx"], False),  # a candidate never replaces it
        (["--action", "squat"], False),  # nor does a restricted grid
        (["--param", "subject"], False),
    ],
)
def test_only_the_shipped_models_whole_grid_writes_the_docs_table(
    extra: list[str], shipped_doc: bool, tmp_path: Path
) -> None:
    args = coverage.build_parser().parse_args(["--cache", str(tmp_path), *extra])
    target = coverage.doc_target(args)
    assert (target == coverage.DOC) is shipped_doc
    assert coverage.shipped_whole_grid(args) is shipped_doc  # and only it goes into the card
    if not shipped_doc:
        assert target == tmp_path / "coverage.md"
    chosen = coverage.build_parser().parse_args([*extra, "--write", str(tmp_path / "x.md")])
    assert coverage.doc_target(chosen) == tmp_path / "x.md"
