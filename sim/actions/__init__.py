"""Kinematic recipes, one per action, and the registry the scene builder uses.

A recipe is ``(ctx, spec, place) -> Segment``: it starts and ends in the
neutral stand at ``place`` (see ``base.py``).
"""

from __future__ import annotations

from collections.abc import Callable

from scotti.sim.actions.backward import backward_walking
from scotti.sim.actions.base import ActionSpec, Context, Place, Segment, stand
from scotti.sim.actions.gait import in_place_walking, side_walking, walking
from scotti.sim.actions.jump import jump
from scotti.sim.actions.step_up import step_up
from scotti.sim.actions.strength import lunge, squat

Recipe = Callable[[Context, ActionSpec, Place], Segment]

RECIPES: dict[str, Recipe] = {
    "squat": squat,
    "lunge": lunge,
    "step_up": step_up,
    "jump": jump,
    "side_walking": side_walking,
    "in_place_walking": in_place_walking,
    "backward_walking": backward_walking,
    "walking": walking,
}

__all__ = ["RECIPES", "ActionSpec", "Context", "Place", "Recipe", "Segment", "stand"]
