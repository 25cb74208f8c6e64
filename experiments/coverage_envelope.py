"""Where each swept field holds: along its values, the run of cells in which every
action meets the cell goals (accuracy, APP, wrong answers that go out), and the
first values on either side where one does not, with the action and the figure
that broke.

A field whose default is a value of its own range (``script.tempo`` = 1) is read
from that value outwards, its baseline cells standing for it; an effect's
parameter from the cell of that effect at its defaults (``effects = noise``); a
field drawn per person (height, the insole's curve) has no single default, so its
run is the longest one among the swept values. A cell whose motion is the
baseline's (``=`` in the grid) counts as the baseline. A cell the simulator
refused or that gave no prediction breaks the run: there the daemon is of no use.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Final

from common import table
from coverage_doc_rows import (
    GOAL_CELL_ACCURACY,
    GOAL_CELL_APP,
    GOAL_WRONG_UNFLAGGED,
    Row,
    Summary,
    num,
    pct,
    show,
)

SHOWN: Final = 3  # actions named where a run breaks; the accuracy grid has every one


def shortfall(row: Row) -> str | None:
    """Why a scored cell misses the cell goals (None: it meets them)."""
    if row.error:
        return "refused by the simulator"
    if row.accuracy is None:
        return "no prediction"
    misses = []
    if row.accuracy < GOAL_CELL_ACCURACY:
        misses.append(f"accuracy {pct(row.accuracy)}")
    if row.app is not None and row.app < GOAL_CELL_APP:
        misses.append(f"APP {num(row.app)}")
    wrong = row.counts.share("wrong_unflagged") or 0.0
    if wrong > GOAL_WRONG_UNFLAGGED:
        misses.append(f"wrong and unflagged {pct(wrong)}")
    return ", ".join(misses) or None


@dataclass(frozen=True)
class Point:
    """One value of a field: per action, None where the cell meets the goals, else why not."""

    value: float
    misses: dict[str, str]
    complete: bool  # every action's cell is scored

    @property
    def holds(self) -> bool:
        return self.complete and not self.misses


@dataclass(frozen=True)
class Envelope:
    path: str
    low: float  # the swept range
    high: float
    run: tuple[float, float] | None  # the values where every action holds (None: nowhere)
    below: Point | None  # the first value under the run that breaks it
    above: Point | None
    complete: bool


def envelopes(summary: Summary, rows: Sequence[Row]) -> list[Envelope]:
    """One per swept field whose values are numbers, in the grid's order."""
    by_cell = {(r.action, r.label): r for r in rows}
    out = []
    for p in summary.parameters:
        values = [v for v in p.values if _is_number(v)]
        if len(values) != len(p.values) or not values:
            continue  # choices, the effects list
        start = _default_point(p.path, p.default, summary.actions, by_cell)
        points = [_point(p.path, v, summary.actions, by_cell, start) for v in values]
        if start is not None and all(pt.value != start.value for pt in points):
            points.append(start)
        points.sort(key=lambda pt: pt.value)
        out.append(_envelope(p.path, points, start))
    return out


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _default_point(
    path: str, default: Any, actions: Sequence[str], by_cell: dict[tuple[str, str], Row]
) -> Point | None:
    """The field at its default, read from the cells that stand for it."""
    if path.startswith("effects.") and _is_number(default):
        effect = path.split(".")[1]
        return _collect(float(default), actions, by_cell, f"effects = {effect}")
    if _is_number(default):
        return _collect(float(default), actions, by_cell, "baseline")
    return None


def _point(
    path: str,
    value: Any,
    actions: Sequence[str],
    by_cell: dict[tuple[str, str], Row],
    start: Point | None,
) -> Point:
    return _collect(float(value), actions, by_cell, f"{path} = {show(value)}", fallback=start)


def _collect(
    value: float,
    actions: Sequence[str],
    by_cell: dict[tuple[str, str], Row],
    label: str,
    fallback: Point | None = None,
) -> Point:
    misses: dict[str, str] = {}
    complete = True
    for action in actions:
        row = by_cell.get((action, label))
        if row is not None and row.unchanged:
            row = by_cell.get((action, "baseline"))
        if row is None:
            complete = False
            continue
        why = shortfall(row)
        if why is not None:
            misses[action] = why
    return Point(value, misses, complete)


def _envelope(path: str, points: list[Point], start: Point | None) -> Envelope:
    low, high = points[0].value, points[-1].value  # the default's point included
    complete = all(pt.complete for pt in points)
    if start is not None:
        centre = next(i for i, pt in enumerate(points) if pt.value == start.value)
        run = _run_around(points, centre) if points[centre].holds else None
    else:
        run = _longest_run(points)
    if run is None:
        return Envelope(path, low, high, None, None, None, complete)
    first, last = run
    below = points[first - 1] if first > 0 else None
    above = points[last + 1] if last + 1 < len(points) else None
    return Envelope(
        path, low, high, (points[first].value, points[last].value), below, above, complete
    )


def _run_around(points: list[Point], centre: int) -> tuple[int, int]:
    first = last = centre
    while first > 0 and points[first - 1].holds:
        first -= 1
    while last + 1 < len(points) and points[last + 1].holds:
        last += 1
    return first, last


def _longest_run(points: list[Point]) -> tuple[int, int] | None:
    best: tuple[int, int] | None = None
    i = 0
    while i < len(points):
        if not points[i].holds:
            i += 1
            continue
        j = i
        while j + 1 < len(points) and points[j + 1].holds:
            j += 1
        if best is None or j - i > best[1] - best[0]:
            best = (i, j)
        i = j + 1
    return best


def _break(point: Point | None) -> str:
    if point is None:
        return "-"
    if not point.complete and not point.misses:
        return f"{_value(point.value)}: not scored yet"
    reasons = set(point.misses.values())
    if len(point.misses) > 1 and len(reasons) == 1 and point.complete:
        return f"{_value(point.value)}: {len(point.misses)} actions ({reasons.pop()})"
    named = [f"{a} ({why})" for a, why in point.misses.items()]
    more = f"; {len(named) - SHOWN} more" if len(named) > SHOWN else ""
    return f"{_value(point.value)}: {'; '.join(named[:SHOWN])}{more}"


def _value(value: float) -> str:
    return f"{value:g}"


def envelope_table(summary: Summary, rows: Sequence[Row]) -> list[str]:
    found = envelopes(summary, rows)
    if not found:
        return ["No numeric field scored yet."]
    body = []
    for e in found:
        if e.run is None:
            held = "nowhere"
        elif e.run == (e.low, e.high):
            held = "the whole range"
        else:
            held = f"{_value(e.run[0])} to {_value(e.run[1])}"
        if not e.complete:
            held += " (incomplete)"
        body.append(
            [e.path, f"{_value(e.low)} to {_value(e.high)}", held, _break(e.below), _break(e.above)]
        )
    return [
        "Along each numeric field's swept values, the run where every action's cell meets "
        f"the cell goals (accuracy >= {pct(GOAL_CELL_ACCURACY)}, APP >= {GOAL_CELL_APP}, at "
        f"most {pct(GOAL_WRONG_UNFLAGGED)} of predictions wrong and unflagged), read from the "
        "field's default outwards where it has one (the baseline, or the effect at its "
        "defaults), else the longest such run; and the first value on each side that "
        f"breaks it, with the actions that miss and by what (the first {SHOWN}, in the "
        "contract's order; every cell: the accuracy grid below). Between two swept values "
        "nothing was measured: a run ends somewhere between its last value and the break.",
        "",
        *table(["field", "swept", "every action holds from", "breaks below", "breaks above"], body),
    ]
