"""docs/coverage.md's opening sections: the headline (the worst cell), the tally of
cells, the baseline and cells by action, the goals, and the unfamiliar flag read as a
detector of wrong predictions."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from common import table
from coverage_doc_rows import (
    GOAL_CELL_ACCURACY,
    GOAL_CELL_APP,
    GOAL_SCENE_ACCURACY,
    GOAL_SCENE_APP,
    GOAL_WRONG_UNFLAGGED,
    Row,
    Summary,
    num,
    pct,
    ratio,
    scene_accuracy,
    sort_key,
    verdict,
)
from coverage_score import CONFIDENT, Counts, detector


def headline(scored: Sequence[Row]) -> list[str]:
    if not scored:
        return ["No cell scored yet."]
    worst = min(scored, key=lambda r: sort_key(r.accuracy))
    with_app = [r for r in scored if r.app is not None]
    out = [
        f"**Worst cell: {worst.action} with {worst.label}: accuracy "
        f"{pct(worst.accuracy)}, APP {num(worst.app)}** ({pct(worst.counts.share('flagged'))} "
        "of its predictions flagged, so withheld by the daemon).",
    ]
    if with_app:
        low = min(with_app, key=lambda r: sort_key(r.app))
        out.append(
            f"Lowest APP: {low.action} with {low.label}: APP {num(low.app)} "
            f"(accuracy {pct(low.accuracy)})."
        )
    loud = max(scored, key=lambda r: r.counts.share("wrong_unflagged") or 0.0)
    out.append(
        f"Most wrong answers published (wrong and unflagged): {loud.action} with "
        f"{loud.label}: {pct(loud.counts.share('wrong_unflagged'))} of its predictions, "
        f"{pct(loud.counts.share('wrong_unflagged_confident'))} at a top probability "
        f"above {CONFIDENT} (accuracy {pct(loud.accuracy)}; read as {loud.read_as()})."
    )
    return [" ".join(out)]


def by_action(summary: Summary, rows: Sequence[Row]) -> list[str]:
    body = []
    for action in summary.actions:
        mine = [r for r in rows if r.action == action and not r.unchanged]
        scored = [r for r in mine if r.accuracy is not None]
        base = next((r for r in mine if r.path is None), None)
        if not scored or base is None:
            continue
        worst = min(scored, key=lambda r: sort_key(r.accuracy))
        loud = max(scored, key=lambda r: r.counts.share("wrong_unflagged") or 0.0)
        below = sum(sort_key(r.accuracy) < GOAL_CELL_ACCURACY for r in scored)
        body.append(
            [
                action,
                pct(base.accuracy),
                num(base.app),
                " ".join(pct(a) for a in base.result.get("accuracy_per_person", [])),
                f"{below} of {len(scored)}",
                f"{pct(worst.accuracy)} ({worst.label})",
                f"{pct(loud.counts.share('wrong_unflagged'))} ({loud.label})",
            ]
        )
    return [
        "The baseline (every field at the scene's default) per action, with each person's "
        "accuracy, and the action's cells: how many fall below the goal, the worst, and the "
        "one publishing most wrong answers (wrong and unflagged).",
        "",
        *table(
            [
                "action",
                "baseline accuracy",
                "baseline APP",
                "per person",
                f"cells below {100 * GOAL_CELL_ACCURACY:.0f} %",
                "worst cell",
                "most wrong and unflagged",
            ],
            body,
        ),
    ]


def tally(rows: Sequence[Row], scored: Sequence[Row]) -> str:
    unchanged = sum(r.unchanged for r in rows)
    silent = [r for r in rows if not r.unchanged and not r.error and r.accuracy is None]
    refused = sum(bool(r.error) for r in rows)
    text = (
        f"{len(rows)} cells: {len(scored)} scored, {unchanged} left the action's motion as "
        f"the baseline's (not simulated again)"
    )
    if refused:
        text += f", {refused} refused by the simulator"
    if silent:
        names = "; ".join(f"{r.action}, {r.label}" for r in silent[:6])
        more = f" and {len(silent) - 6} more" if len(silent) > 6 else ""
        text += (
            f", {len(silent)} without a single prediction (the daemon says nothing there, "
            f"which is neither right nor wrong: {names}{more})"
        )
    return text + "."


def goals(scored: Sequence[Row], scenes: Sequence[dict[str, Any]]) -> list[str]:
    rows = []
    if scored:
        worst = min(scored, key=lambda r: sort_key(r.accuracy))
        below = sum(sort_key(r.accuracy) < GOAL_CELL_ACCURACY for r in scored)
        rows.append(
            [
                f"worst cell accuracy >= {100 * GOAL_CELL_ACCURACY:.0f} %",
                f"{pct(worst.accuracy)} ({worst.action}, {worst.label}); "
                f"{below} of {len(scored)} cells below",
                verdict(sort_key(worst.accuracy) >= GOAL_CELL_ACCURACY),
            ]
        )
        with_app = [r for r in scored if r.app is not None]
        if with_app:
            low = min(with_app, key=lambda r: sort_key(r.app))
            below = sum(sort_key(r.app) < GOAL_CELL_APP for r in with_app)
            rows.append(
                [
                    f"worst cell APP >= {GOAL_CELL_APP}",
                    f"{num(low.app)} ({low.action}, {low.label}); "
                    f"{below} of {len(with_app)} cells below",
                    verdict(sort_key(low.app) >= GOAL_CELL_APP),
                ]
            )
        share = [(r.counts.share("wrong_unflagged") or 0.0, r) for r in scored]
        top, top_row = max(share, key=lambda x: x[0])
        over = sum(s > GOAL_WRONG_UNFLAGGED for s, _ in share)
        rows.append(
            [
                f"no cell with > {100 * GOAL_WRONG_UNFLAGGED:.0f} % of predictions wrong "
                "and unflagged",
                f"{over} of {len(scored)} cells over; the most {pct(top)} "
                f"({top_row.action}, {top_row.label})",
                verdict(over == 0),
            ]
        )
    if scenes:
        failing = [
            s["scene_file"]
            for s in scenes
            if sort_key(scene_accuracy(s)) < GOAL_SCENE_ACCURACY
            or sort_key(s["metrics"].get("app"), 1.0) < GOAL_SCENE_APP
        ]
        worst_scene = min(scenes, key=lambda s: sort_key(scene_accuracy(s)))
        rows.append(
            [
                f"every scene in sim/scenes: accuracy >= {100 * GOAL_SCENE_ACCURACY:.0f} %, "
                f"APP >= {GOAL_SCENE_APP}",
                f"{len(failing)} of {len(scenes)} fail"
                + (f" ({', '.join(failing)})" if failing else "")
                + f"; lowest accuracy {pct(scene_accuracy(worst_scene))} "
                f"({worst_scene['scene_file']})",
                verdict(not failing),
            ]
        )
    return table(["goal", "measured", ""], rows)


def unfamiliar_as_detector(scored: Sequence[Row]) -> list[str]:
    total = sum((r.counts for r in scored), Counts())
    if not total.predictions:
        return ["No predictions scored yet."]
    unfamiliar, anyflag = detector(total, "unfamiliar"), detector(total, "flagged")
    return [
        f"Over every scored cell ({total.predictions} predictions with an action label), "
        f"{pct(total.share('wrong'))} are wrong. The daemon withholds a prediction that "
        "carries a flag (`unloaded`, `out_of_range` or `unfamiliar`, models/ood.py); read "
        "as a detector of wrong predictions:",
        "",
        *table(
            [
                "flag",
                "fires on",
                "precision (flagged that are wrong)",
                "recall (wrong that are flagged)",
            ],
            [
                [
                    "unfamiliar",
                    pct(total.share("unfamiliar")),
                    pct(unfamiliar.precision),
                    pct(unfamiliar.recall),
                ],
                [
                    "any flag",
                    pct(total.share("flagged")),
                    pct(anyflag.precision),
                    pct(anyflag.recall),
                ],
            ],
        ),
        "",
        f"A flag fired at random has precision {pct(unfamiliar.base_rate)} (the share "
        "of wrong predictions). Of the wrong predictions, "
        f"{pct(ratio(total.wrong_unflagged, total.wrong))} went out unflagged, "
        f"{pct(ratio(total.wrong_unflagged_confident, total.wrong))} of them at a top "
        f"probability above {CONFIDENT}. Per parameter: the last columns of the table "
        "*Per parameter*.",
    ]
