"""docs/coverage.md's tables: the scene files as shipped, the accuracy grid
(parameter x value by action), a summary per parameter, the worst cells with every
figure, and what is not swept over the schema's range, and why."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Final

from common import table
from coverage_doc_rows import (
    GOAL_CELL_ACCURACY,
    GOAL_SCENE_ACCURACY,
    GOAL_SCENE_APP,
    GOAL_WRONG_UNFLAGGED,
    Row,
    Summary,
    num,
    pct,
    ratio,
    scene_accuracy,
    show,
    sort_key,
    verdict,
)
from coverage_grid import EXTRA_VALUES, NOT_RANGE, SKIPPED, WITH
from coverage_score import CONFIDENT, Counts, detector

WORST_SHOWN: Final = 25


def scene_files(scenes: Sequence[dict[str, Any]]) -> list[str]:
    if not scenes:
        return ["Not scored in this run (--no-scenes)."]
    rows = []
    for s in scenes:
        c = Counts.of(s["counts"])
        m = s["metrics"]
        ok = (
            sort_key(scene_accuracy(s)) >= GOAL_SCENE_ACCURACY
            and sort_key(m.get("app"), 1.0) >= GOAL_SCENE_APP
        )
        rows.append(
            [
                f"`{s['scene_file']}`",
                f"{m['frames'] / 16 / 60:.1f}",
                pct(scene_accuracy(s)),
                num(m.get("app")),
                num(m.get("mpjpe_mm"), 1),
                pct(c.share("unloaded")),
                pct(c.share("out_of_range")),
                pct(c.share("unfamiliar")),
                pct(c.share("wrong_unflagged")),
                verdict(ok),
            ]
        )
    return [
        "Each file rendered as it is (`scotti sim FILE`) and replayed as `scotti eval` "
        "does. Goal: accuracy >= 95 %, APP >= 0.88.",
        "",
        *table(
            [
                "scene",
                "min",
                "accuracy",
                "APP",
                "MPJPE mm",
                "unloaded",
                "out_of_range",
                "unfamiliar",
                "wrong, unflagged",
                "",
            ],
            rows,
        ),
    ]


def accuracy_grid(summary: Summary, rows: Sequence[Row]) -> list[str]:
    by_cell = {(r.action, r.label): r for r in rows}
    labels = ["baseline"] + [f"{p.path} = {show(v)}" for p in summary.parameters for v in p.values]
    body = []
    for label in labels:
        cells = [_acc_cell(by_cell.get((a, label))) for a in summary.actions]
        body.append([label.replace("|", "/"), *cells])
    return [
        "Accuracy (%) of each cell, its people pooled; the baseline row is every field at "
        "the scene's default (the people's own traits, the realistic insole, no effects). "
        f"**Bold**: below {100 * GOAL_CELL_ACCURACY:.0f} %. `=`: the value leaves that "
        "action's motion as the baseline's (a movement field the action does not read): "
        "not simulated again. `n/p`: no prediction at all. `err`: the simulator refused "
        "the scene (listed below the table). Empty: not scored yet.",
        "",
        *table(["parameter = value", *summary.actions], body),
        *_errors(rows),
    ]


def _errors(rows: Sequence[Row]) -> list[str]:
    refused = [r for r in rows if r.error]
    if not refused:
        return []
    out = ["", "Scenes the schema accepts and the simulator refused:", ""]
    return out + [f"- {r.action}, {r.label}: {r.error}" for r in refused]


def _acc_cell(row: Row | None) -> str:
    if row is None:
        return ""
    if row.unchanged:
        return "="
    if row.error:
        return "err"
    if row.accuracy is None:
        return "n/p"
    text = f"{100 * row.accuracy:.1f}"
    return f"**{text}**" if row.accuracy < GOAL_CELL_ACCURACY else text


def per_parameter(summary: Summary, rows: Sequence[Row]) -> list[str]:
    body = []
    for p in summary.parameters:
        mine = [r for r in rows if r.path == p.path and not r.unchanged]
        scored = [r for r in mine if r.accuracy is not None]
        if not scored:
            continue
        worst = min(scored, key=lambda r: sort_key(r.accuracy))
        with_app = [r for r in scored if r.app is not None]
        low = min(with_app, key=lambda r: sort_key(r.app)) if with_app else None
        pooled = sum((r.counts for r in scored), Counts())
        det = detector(pooled, "unfamiliar")
        mpjpe = [r.metric("mpjpe_mm") for r in scored]
        body.append(
            [
                p.path,
                f"{len(scored)}",
                f"{pct(worst.accuracy)} ({worst.action}, {_show_value(worst)})",
                f"{num(low.app)} ({low.action}, {_show_value(low)})" if low else "-",
                num(max((x for x in mpjpe if x is not None), default=None), 0),
                pct(pooled.share("unloaded")),
                pct(pooled.share("out_of_range")),
                pct(pooled.share("unfamiliar")),
                pct(max((r.counts.share("wrong_unflagged") or 0.0) for r in scored)),
                pct(max((r.counts.share("wrong_unflagged_confident") or 0.0) for r in scored)),
                pct(det.base_rate),
                pct(det.precision),
                pct(det.recall),
            ]
        )
    return [
        "Cells scored per parameter (all its values and actions), the worst of them, and "
        "their predictions pooled: flag shares, wrong predictions (the share among all; "
        "the largest share of wrong-and-unflagged and of wrong, unflagged and confident "
        f"(top probability > {CONFIDENT}) in one cell), and the unfamiliar flag as a "
        "detector of wrong ones (precision, recall).",
        "",
        *table(
            [
                "parameter",
                "cells",
                "worst accuracy",
                "worst APP",
                "max MPJPE mm",
                "unloaded",
                "out_of_range",
                "unfamiliar",
                "max wrong unflagged",
                "max wrong confident",
                "wrong",
                "unfamiliar precision",
                "unfamiliar recall",
            ],
            body,
        ),
    ]


def _show_value(row: Row) -> str:
    return row.label.split(" = ", 1)[-1]


def worst_cells(scored: Sequence[Row]) -> list[str]:
    ranked = sorted(scored, key=lambda r: sort_key(r.accuracy))[:WORST_SHOWN]
    body = []
    for r in ranked:
        c = r.counts
        published = c.predictions - c.flagged
        body.append(
            [
                r.action,
                r.label,
                pct(r.accuracy),
                pct(ratio(published - c.wrong_unflagged, published)),
                num(r.app),
                num(r.metric("mpjpe_mm"), 0),
                num(r.metric("progress_mse"), 4),
                pct(c.share("unloaded")),
                pct(c.share("out_of_range")),
                pct(c.share("unfamiliar")),
                pct(c.share("wrong_unflagged")),
                pct(c.share("wrong_unflagged_confident")),
                " ".join(pct(a) for a in r.result.get("accuracy_per_person", [])),
            ]
        )
    return [
        "Accuracy over every prediction (as `scotti eval`), and over the published ones "
        "(those no flag withholds); shares of all predictions.",
        "",
        *table(
            [
                "action",
                "parameter = value",
                "accuracy",
                "published accuracy",
                "APP",
                "MPJPE mm",
                "progress MSE",
                "unloaded",
                "out_of_range",
                "unfamiliar",
                "wrong, unflagged",
                "wrong, unflagged, confident",
                "accuracy per person",
            ],
            body,
        ),
    ]


def published_wrong(scored: Sequence[Row]) -> list[str]:
    """Every cell over the goal for wrong answers that go out, most first, with what
    they were read as: whether the motion is another action's (side steps of no length
    are steps in place) or the model's mistake is for a reader to judge, not a count."""
    over = [r for r in scored if (r.counts.share("wrong_unflagged") or 0.0) > GOAL_WRONG_UNFLAGGED]
    over.sort(key=lambda r: -(r.counts.share("wrong_unflagged") or 0.0))
    if not over:
        return [f"No cell publishes more than {pct(GOAL_WRONG_UNFLAGGED)} wrong answers."]
    body = [
        [
            r.action,
            r.label,
            pct(r.counts.share("wrong_unflagged")),
            pct(r.counts.share("wrong_unflagged_confident")),
            r.read_as(),
            pct(r.accuracy),
            pct(r.counts.share("unfamiliar")),
        ]
        for r in over
    ]
    return [
        f"Every cell where more than {pct(GOAL_WRONG_UNFLAGGED)} of the predictions are wrong "
        "and go out unflagged, most first; `read as`: the actions those wrong answers named, "
        "as shares of all the cell's predictions.",
        "",
        *table(
            [
                "action",
                "parameter = value",
                "wrong, unflagged",
                "of which confident",
                "read as",
                "accuracy",
                "unfamiliar",
            ],
            body,
        ),
    ]


def declared_ranges() -> list[str]:
    out = [f"- `{path}`: not swept: {why}" for path, why in SKIPPED.items()]
    out += [
        f"- `{path}`: swept at {', '.join(map(show, values))}: {why}"
        for path, (why, values) in NOT_RANGE.items()
    ]
    out += [
        f"- `{path}`: also at {', '.join(map(show, values))}: {why}"
        for path, (why, values) in EXTRA_VALUES.items()
    ]
    out += [
        f"- `{path}`: with {', '.join(f'{k} = {v}' for k, v in given.items())}: {why}"
        for path, (why, given) in WITH.items()
    ]
    out.append(
        "- An open bound (a value that must be greater than its minimum) is approached "
        "to 0.01 % of the field's span; an extreme that is the field's default is the "
        "baseline's cell (for an effect's parameter: the cell of that effect at its defaults)."
    )
    return out
