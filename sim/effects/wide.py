"""Effects drawn over everything a scene accepts, for ``scotti sim corpus --effects wide``.

The realistic preset (``registry.realistic_effects``) keeps every effect
inside its documented typical range, so a model trained on it never meets a
hysteresis of 0.8, a radio link that stays bad or one insole a second late,
which a scene may ask for and the coverage grid scores (docs/coverage.md).
A wide draw starts from the realistic one and draws ``WIDENED_PER_DRAW`` of
the ``WIDENED`` effects again, each parameter uniform over the range its
model accepts (a literal: one of its values): one person's transport is
far off in a few ways, not destroyed in every way at once.

Two effects are not widened, because the model meets them as something
that is: line corruption arrives as lost packets (the frame's CRC drops
them: packet loss), and an unplugged receiver as a window that starts
again (every session's start).
"""

from __future__ import annotations

from typing import Any, Final, Literal, get_args, get_origin

import numpy as np
from scotti.sim.effects.registry import EFFECT_MODELS, realistic_effects
from scotti.sim.field_range import field_range

WIDENED: Final = (
    "hysteresis",
    "creep",
    "crosstalk",
    "dead_line",
    "noise",
    "clock_drift",
    "packet_loss",
    "foot_offset",
    "jitter",
)
WIDENED_PER_DRAW: Final = 3


def schema_draw(name: str, rng: np.random.Generator) -> dict[str, Any]:
    """One effect's table with every parameter drawn over the range its model accepts."""
    model = EFFECT_MODELS[name]
    table: dict[str, Any] = {"name": name}
    for field_name, field in model.model_fields.items():
        kind = field.annotation
        if get_origin(kind) is Literal:
            table[field_name] = str(rng.choice(get_args(kind)))
            continue
        low, high = field_range(model, field_name)
        if kind is int:
            table[field_name] = int(rng.integers(int(low), int(high) + 1))
        else:
            # A lower bound that is open (a time constant above 0) is never drawn:
            # uniform(low, high) returns low with probability 0, but not never.
            table[field_name] = float(max(rng.uniform(low, high), np.nextafter(low, high)))
    model.model_validate({k: v for k, v in table.items() if k != "name"})  # the scene's own check
    return table


def wide_effects(
    realistic_rng: np.random.Generator, wide_rng: np.random.Generator
) -> list[dict[str, Any]]:
    """The realistic draw of ``realistic_rng``, with ``WIDENED_PER_DRAW`` effects drawn
    again over their whole range by ``wide_rng`` (added where the realistic draw has none)."""
    effects = realistic_effects(realistic_rng)
    chosen = [str(n) for n in wide_rng.choice(WIDENED, WIDENED_PER_DRAW, replace=False)]
    widened = {name: schema_draw(name, wide_rng) for name in chosen}
    kept = [e for e in effects if e["name"] not in widened]
    return kept + [widened[name] for name in chosen]
