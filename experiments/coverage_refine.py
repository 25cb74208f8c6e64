"""The grid refined where a field stops holding: between the last value of a
field's run (docs/coverage.md, "Where each field holds") and the first value
that breaks it, one more value, for every action. ``--refine N`` does N rounds,
each halving the span where the edge lies (by ratio where the two values are
``GEOMETRIC_RATIO`` or more apart, as the grid spaces its interior points), so
the table says where a field stops to within a sixteenth of that span after four.

Fields swept at declared values (``NOT_RANGE``: the renderer's rates) or at their
ends only (``NO_INTERIOR``) are not refined.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from coverage_doc_rows import Row, Summary
from coverage_envelope import envelopes
from coverage_grid import GEOMETRIC_RATIO, NO_INTERIOR, NOT_RANGE, Parameter


def midpoint(a: float, b: float, integer: bool) -> float | int | None:
    """The value halfway between ``a`` and ``b`` (by ratio when both are positive and
    GEOMETRIC_RATIO apart), to three significant digits or the nearest integer; None when
    that is one of them (nothing left between)."""
    low, high = sorted((a, b))
    mid = math.sqrt(low * high) if low > 0 and high / low >= GEOMETRIC_RATIO else (low + high) / 2
    value: float | int = round(mid) if integer else float(f"{mid:.3g}")
    return value if low < value < high else None


def refinements(summary: Summary, rows: Sequence[Row]) -> dict[str, tuple[Any, ...]]:
    """Per field, the values to add: one between each end of its run and the break there."""
    by_path = {p.path: p for p in summary.parameters}
    out: dict[str, tuple[Any, ...]] = {}
    for e in envelopes(summary, rows):
        if e.run is None or not e.complete or e.path in NOT_RANGE or e.path in NO_INTERIOR:
            continue
        integer = all(isinstance(v, int) for v in by_path[e.path].values)
        added = []
        for edge, broken in ((e.run[0], e.below), (e.run[1], e.above)):
            if broken is None:
                continue
            mid = midpoint(edge, broken.value, integer)
            if mid is not None and mid not in by_path[e.path].values:
                added.append(mid)
        if added:
            out[e.path] = tuple(added)
    return out


def refined(
    parameters: Sequence[Parameter], added: dict[str, tuple[Any, ...]]
) -> tuple[Parameter, ...]:
    """The parameters with the added values among theirs, in order."""
    return tuple(
        Parameter(p.path, tuple(sorted({*p.values, *added[p.path]})), p.default)
        if p.path in added
        else p
        for p in parameters
    )
