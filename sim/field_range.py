"""The range a scene accepts for one numeric field of a pydantic model, read from its constraints.

The wide draws of a corpus (``corpus.wide_body``, ``effects.wide``) draw values
over exactly what the schema accepts, so they read the bounds from the model
rather than repeat them.
"""

from __future__ import annotations

from pydantic import BaseModel


def field_range(model: type[BaseModel], name: str) -> tuple[float, float]:
    """(low, high) a numeric field accepts (an open bound is taken as closed)."""
    low = high = None
    for m in model.model_fields[name].metadata:  # pydantic's Ge, Gt, Le, Lt constraints
        bound = getattr(m, "ge", getattr(m, "gt", None))
        if bound is not None:
            low = float(bound)
        bound = getattr(m, "le", getattr(m, "lt", None))
        if bound is not None:
            high = float(bound)
    if low is None or high is None:
        msg = f"{model.__name__}.{name} has no closed range to draw from"
        raise ValueError(msg)
    return low, high
