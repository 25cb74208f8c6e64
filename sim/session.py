"""A session like a lab recording: sets in varied order, standing between, walking between.

A generated session (a scene's ``[session]`` table) asks for minutes per
action. Each action's minutes are cut into sets of varied length (uniform
in ``set_s``, the last one takes the remainder); the sets of all actions are
shuffled so that no action follows itself; and the person moves between
them as in a lab:

    stand (lead-in) | walk to the next spot or turn round | stand, ready |
    SET | stand, resting | walk to the next spot ... | SET | stand, resting

Stands are labelled ``standing`` (NO_ACTION until the contract has it, see
``STANDING``); the walks between sets are transitions, NO_ACTION. Sets
vary (``ActionSpec.vary``): walking sets follow a walkway with turns and
speed changes, side walking changes direction from set to set. Should a set
come out shorter than asked (repetitions are whole), more sets of that
action are added at the end, so every action gets at least its minutes.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Final, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator
from scotti.models.contract import ACTIONS, STANDING
from scotti.sim.actions import EXERCISES, RECIPES, ActionSpec, Context, Place, Segment, stand
from scotti.sim.actions.gait import transition_walk

LEAD_IN_S: Final = (2.0, 5.0)  # standing before the first transition
READY_S: Final = (1.0, 3.0)  # standing after a transition, before the set
WALK_STEPS: Final = (3, 6)  # steps to the next spot (inclusive)
WALK_TURN_RAD: Final = np.radians(120.0)  # largest heading change on the way
TURN_ROUND_SHARE: Final = 0.35  # transitions that turn round on the spot
TURN_ROUND_AFTER_WALKING: Final = 0.6  # ... after a walking set (end of the walkway)
TURN_ROUND_RAD: Final = (np.radians(160.0), np.radians(200.0))
TURN_ROUND_STEPS: Final = 5
TURN_ROUND_LENGTH: Final = 0.12  # share of the person's step length: turning on the spot
STEP_BOX_M: Final = (0.15, 0.25)  # the lab's step for step-ups, one per session
# Sets are asked a little longer than their share: repetitions are whole and
# a set may end short of its time; a set that tops up what is missing is
# at least this long.
SET_MARGIN: Final = 1.08
TOP_UP_S: Final = 10.0


@dataclass(frozen=True)
class Item:
    """One part of a session plan: a set, a stand, or a walk between spots."""

    kind: str  # "set", "stand" or "transition"
    seconds: float = 0.0  # set: asked duration; stand: duration
    action: str = ""  # set only
    steps: int = 0  # transition only
    turn_rad: float = 0.0  # transition only
    length_scale: float = 1.0  # transition only


@dataclass(frozen=True)
class Part:
    """An item as built: where its frames lie in the session."""

    item: Item
    start: int  # first frame
    frames: int


def cut_sets(seconds: float, set_s: tuple[float, float], rng: np.random.Generator) -> list[float]:
    """Set lengths (uniform in ``set_s``) that add up to ``seconds``; the last takes the rest."""
    out: list[float] = []
    left = seconds
    while left > 1e-9:
        length = float(rng.uniform(*set_s))
        if left - length < set_s[0]:  # the rest would be too short a set
            length = left if left <= set_s[1] else left / 2
        out.append(length)
        left -= length
    return out


def order_sets(sets: list[tuple[str, float]], rng: np.random.Generator) -> list[tuple[str, float]]:
    """A random order of the sets in which, where it can be helped, no action follows itself.

    Each next set is drawn among the other actions' sets, in proportion to
    how many each has left; an action holding more than half of what is
    left goes next (else it would have to follow itself later).
    """
    left: dict[str, list[float]] = {}
    for action, seconds in [sets[i] for i in rng.permutation(len(sets))]:
        left.setdefault(action, []).append(seconds)
    order: list[tuple[str, float]] = []
    previous = ""
    while left:
        total = sum(len(v) for v in left.values())
        names = sorted(left)
        crowded = [a for a in names if 2 * len(left[a]) > total + (a == previous)]
        choices = crowded or [a for a in names if a != previous] or names
        weights = np.array([len(left[a]) for a in choices], dtype=np.float64)
        action = choices[int(rng.choice(len(choices), p=weights / weights.sum()))]
        order.append((action, left[action].pop()))
        if not left[action]:
            del left[action]
        previous = action
    return order


def plan_session(
    minutes: Mapping[str, float],
    set_s: tuple[float, float],
    rest_s: tuple[float, float],
    rng: np.random.Generator,
) -> list[Item]:
    """The items of a session: every action's minutes as sets, with stands and walks between."""
    sets = [(a, s * SET_MARGIN) for a, m in minutes.items() for s in cut_sets(60.0 * m, set_s, rng)]
    items = [Item("stand", float(rng.uniform(*LEAD_IN_S)))]
    previous = ""
    for action, seconds in order_sets(sets, rng):
        items += _between(previous, action, rest_s, rng)
        items.append(Item("set", seconds, action))
        previous = action
    items.append(Item("stand", float(rng.uniform(*rest_s))))
    return items


def _between(
    previous: str, action: str, rest_s: tuple[float, float], rng: np.random.Generator
) -> list[Item]:
    """Rest after the last set (if any), a walk or a turn, a moment to get ready."""
    out = [Item("stand", float(rng.uniform(*rest_s)))] if previous else []
    turn_round = TURN_ROUND_AFTER_WALKING if previous == "walking" else TURN_ROUND_SHARE
    if rng.random() < turn_round:
        sign = 1.0 if rng.random() < 0.5 else -1.0
        turn = sign * float(rng.uniform(*TURN_ROUND_RAD))
        out.append(Item("transition", steps=TURN_ROUND_STEPS, turn_rad=turn,
                        length_scale=TURN_ROUND_LENGTH))  # fmt: skip
    else:
        steps = int(rng.integers(WALK_STEPS[0], WALK_STEPS[1] + 1))
        turn = float(rng.uniform(-WALK_TURN_RAD, WALK_TURN_RAD))
        out.append(Item("transition", steps=steps, turn_rad=turn))
    out.append(Item("stand", float(rng.uniform(*READY_S))))
    return out


def build_session(
    ctx: Context,
    items: list[Item],
    minutes: Mapping[str, float],
    rest_s: tuple[float, float],
    rng: np.random.Generator,
) -> tuple[list[Segment], list[Part]]:
    """Run a plan from the origin; top up any action that came out short of its minutes."""
    place = Place(0.0, 0.0, 0.0)
    step_box = float(rng.uniform(*STEP_BOX_M))
    segments: list[Segment] = []
    parts: list[Part] = []
    done = dict.fromkeys(minutes, 0.0)
    frames = 0
    queue = list(items)
    while queue:
        item = queue.pop(0)
        segment = _build(ctx, item, place, step_box, rng)
        place = segment.end
        segments.append(segment)
        parts.append(Part(item, frames, len(segment)))
        frames += len(segment)
        if item.kind == "set":
            own = int(np.count_nonzero(segment.action == ACTIONS.index(item.action)))
            done[item.action] += own / ctx.rate_hz
        if not queue:
            short = {a: 60.0 * m - done[a] for a, m in minutes.items() if done[a] < 60.0 * m}
            last = parts[-1].item.action if parts else ""
            for action, missing in short.items():
                queue += _between(last, action, rest_s, rng)
                queue.append(Item("set", max(missing + 2.0, TOP_UP_S), action))
                last = action
            if short:
                queue.append(Item("stand", float(rng.uniform(*rest_s))))
    return segments, parts


def _build(
    ctx: Context, item: Item, place: Place, step_box: float, rng: np.random.Generator
) -> Segment:
    if item.kind == "stand":
        segment = stand(ctx, place, item.seconds)
        label = STANDING
        return Segment(
            segment.params, np.full(len(segment), label, np.int64), segment.end, segment.ground_z
        )
    if item.kind == "transition":
        return transition_walk(ctx, place, item.steps, item.turn_rad, item.length_scale)
    direction = "left" if rng.random() < 0.5 else "right"
    spec = ActionSpec(
        item.action,
        duration_s=item.seconds,
        step_height_m=step_box,
        direction=direction,
        vary=True,
    )
    return RECIPES[item.action](ctx, spec, place)


class SessionModel(BaseModel):
    """A scene's ``[session]`` table: what to record, validated."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    actions: list[Literal[EXERCISES]] = Field(  # type: ignore[valid-type]
        default_factory=lambda: list(EXERCISES), min_length=1
    )
    minutes_per_action: float | dict[str, float] = 4.0
    set_s: tuple[float, float] = (30.0, 75.0)
    rest_s: tuple[float, float] = (5.0, 20.0)
    seed: int | None = None

    @model_validator(mode="after")
    def _ranges(self) -> SessionModel:
        for name in ("set_s", "rest_s"):
            low, high = getattr(self, name)
            if not 0.0 < low <= high <= 3600.0:
                msg = f"{name} must be [low, high] with 0 < low <= high <= 3600"
                raise ValueError(msg)
        for action, minutes in self.minutes().items():
            if not 0.0 < minutes <= 600.0:
                msg = f"minutes_per_action for {action} must be in (0, 600]"
                raise ValueError(msg)
        return self

    def minutes(self) -> dict[str, float]:
        """Minutes per asked action (a table names some; the others are not asked)."""
        if isinstance(self.minutes_per_action, dict):
            unknown = sorted(set(self.minutes_per_action) - set(self.actions))
            if unknown:
                msg = f"minutes_per_action names actions not asked for: {', '.join(unknown)}"
                raise ValueError(msg)
            missing = [a for a in self.actions if a not in self.minutes_per_action]
            if missing:
                msg = f"minutes_per_action gives no minutes for {', '.join(missing)}"
                raise ValueError(msg)
            return {a: float(self.minutes_per_action[a]) for a in self.actions}
        return dict.fromkeys(self.actions, float(self.minutes_per_action))


def session_segments(session: SessionModel, ctx: Context, scene_seed: int) -> list[Segment]:
    """The segments of a generated lab session (its plan drawn from its own seed)."""
    seed = scene_seed if session.seed is None else session.seed
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x5E55]))
    minutes = session.minutes()
    items = plan_session(minutes, session.set_s, session.rest_s, rng)
    segments, _ = build_session(ctx, items, minutes, session.rest_s, rng)
    return segments
