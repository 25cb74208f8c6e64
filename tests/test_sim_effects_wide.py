"""Wide effects: the realistic draw with a few effects drawn over all a scene accepts."""

from __future__ import annotations

from typing import Literal, get_args, get_origin

import numpy as np
import pytest
from scotti.sim.effects.registry import EFFECT_MODELS, parse_effects, realistic_effects
from scotti.sim.effects.transport import UnplugParams
from scotti.sim.effects.wide import (
    WIDENED,
    WIDENED_PER_DRAW,
    schema_draw,
    wide_effects,
)
from scotti.sim.field_range import field_range


def _draws(count: int) -> list[list[dict[str, object]]]:
    return [
        wide_effects(np.random.default_rng([4, i, 1]), np.random.default_rng([4, i, 2]))
        for i in range(count)
    ]


def test_each_draw_keeps_the_realistic_draw_but_for_the_widened_effects() -> None:
    for i, effects in enumerate(_draws(40)):
        realistic = {e["name"]: e for e in realistic_effects(np.random.default_rng([4, i, 1]))}
        drawn = {e["name"]: e for e in effects}
        assert len(drawn) == len(effects)  # one table per effect
        changed = {n for n, e in drawn.items() if realistic.get(n) != e}
        assert len(changed) == WIDENED_PER_DRAW
        assert changed <= set(WIDENED)
        assert set(realistic) <= set(drawn)  # nothing of the realistic draw is dropped
        # line corruption arrives as packet loss, an unplug as a new window: never widened
        assert drawn["line_corruption"] == realistic["line_corruption"]
        assert "unplug" not in drawn
        assert len(parse_effects(effects)) == len(effects)  # every table is one a scene may give


def test_the_draws_reach_both_ends_of_every_widened_parameter() -> None:
    rng = np.random.default_rng(11)
    for name in WIDENED:
        tables = [schema_draw(name, rng) for _ in range(200)]
        model = EFFECT_MODELS[name]
        for field_name, field in model.model_fields.items():
            values = [t[field_name] for t in tables]
            if get_origin(field.annotation) is Literal:
                assert set(values) == set(get_args(field.annotation)), (name, field_name)
                continue
            low, high = field_range(model, field_name)
            span = high - low
            assert min(values) >= low, (name, field_name)
            assert max(values) <= high, (name, field_name)
            assert min(values) < low + 0.1 * span, (name, field_name)
            assert max(values) > high - 0.1 * span, (name, field_name)


def test_every_widened_effect_is_widened_in_some_draws() -> None:
    counts = dict.fromkeys(WIDENED, 0)
    realistic_names = {e["name"] for e in realistic_effects(np.random.default_rng(0))}
    for i, effects in enumerate(_draws(90)):
        realistic = {e["name"]: e for e in realistic_effects(np.random.default_rng([4, i, 1]))}
        for e in effects:
            if realistic.get(str(e["name"])) != e:
                counts[str(e["name"])] += 1
    assert all(c >= 10 for c in counts.values()), counts  # 90 x 3 / 9 = 30 expected each
    assert "dead_line" not in realistic_names  # the one widening adds, not replaces


def test_a_parameter_without_an_upper_bound_is_refused_by_name() -> None:
    with pytest.raises(ValueError, match=r"UnplugParams\.start_s"):
        field_range(UnplugParams, "start_s")
