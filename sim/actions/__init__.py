"""Kinematic recipes, one per action, and the registry the scene builder uses.

A recipe is ``(ctx, spec, place) -> Segment``: it starts and ends in the
neutral stand at ``place`` (see ``base.py``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np
from scotti.models.contract import ACTIONS
from scotti.sim.actions.backward import backward_walking
from scotti.sim.actions.base import ActionSpec, Context, Place, Segment, stand, standing_label
from scotti.sim.actions.gait import in_place_walking, side_walking, walking
from scotti.sim.actions.jump import jump
from scotti.sim.actions.step_up import step_up
from scotti.sim.actions.strength import lunge, squat

Recipe = Callable[[Context, ActionSpec, Place], Segment]


def standing(ctx: Context, spec: ActionSpec, place: Place) -> Segment:
    """A quiet stand as an action: ``duration_s``, or 2 s per ``reps``."""
    seconds = spec.duration_s if spec.duration_s is not None else 2.0 * (spec.reps or 1)
    segment = stand(ctx, place, seconds)
    return replace(segment, action=np.full(len(segment), standing_label(), dtype=np.int64))


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
if "standing" in ACTIONS:  # the ninth action, once the contract has it
    RECIPES["standing"] = standing
# The actions a person is asked to do (sets); standing is what they do between.
EXERCISES: tuple[str, ...] = tuple(a for a in ACTIONS if a != "standing")

__all__ = [
    "EXERCISES",
    "RECIPES",
    "ActionSpec",
    "Context",
    "Place",
    "Recipe",
    "Segment",
    "stand",
    "standing",
    "standing_label",
]
