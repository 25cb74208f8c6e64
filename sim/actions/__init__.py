"""Kinematic recipes, one per action, and the registry the scene builder uses.

A recipe is ``(ctx, spec, place) -> Segment``: it starts and ends in the
neutral stand at ``place`` (see ``base.py``).
"""

from __future__ import annotations

from collections.abc import Callable

from scotti.models.contract import ACTIONS
from scotti.sim.actions.backward import backward_walking
from scotti.sim.actions.base import ActionSpec, Context, Place, Segment, stand
from scotti.sim.actions.gait import in_place_walking, side_walking, walking
from scotti.sim.actions.jump import jump
from scotti.sim.actions.step_up import step_up
from scotti.sim.actions.strength import lunge, squat

Recipe = Callable[[Context, ActionSpec, Place], Segment]

# A scripted stand counts its "repetitions" in sway cycles (0.4 Hz, see ``stand``).
STANDING_CYCLE_S = 2.5


def standing(ctx: Context, spec: ActionSpec, place: Place) -> Segment:
    """Standing as a scripted action: the quiet stand for ``duration_s`` or ``reps`` cycles."""
    reps = spec.reps if spec.reps is not None else 1
    return stand(ctx, place, spec.duration_s or reps * STANDING_CYCLE_S)


RECIPES: dict[str, Recipe] = {
    "squat": squat,
    "lunge": lunge,
    "step_up": step_up,
    "jump": jump,
    "side_walking": side_walking,
    "in_place_walking": in_place_walking,
    "backward_walking": backward_walking,
    "walking": walking,
    "standing": standing,
}
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
]
