"""Lab sessions: every asked action for its minutes, in sets, standing and walking between."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scotti.models.contract import ACTIONS, NO_ACTION, STANDING
from scotti.sim.actions import Context
from scotti.sim.motion import Subject
from scotti.sim.scene import Scene, SceneError, build_motion, motion_from_segments
from scotti.sim.session import Part, build_session, cut_sets, order_sets, plan_session

ASKED = {"squat": 0.4, "walking": 0.4, "side_walking": 0.3, "jump": 0.3}
SET_S = (8.0, 15.0)
REST_S = (3.0, 6.0)


def _session(style_seed: int, seed: int) -> tuple[list[Part], np.ndarray, np.ndarray]:
    """Parts, labels and world keypoints of a generated session."""
    subject = Subject(1.72, 66.0, style_seed=style_seed)
    body = subject.body()
    ctx = Context(body, subject, 16.0, np.random.default_rng(seed))
    rng = np.random.default_rng(seed + 1)
    items = plan_session(ASKED, SET_S, REST_S, rng)
    segments, parts = build_session(ctx, items, ASKED, REST_S, rng)
    motion = motion_from_segments(body, subject, 16.0, segments)
    return parts, motion.action, motion.world


def test_a_session_holds_every_asked_action_for_its_minutes_with_stands_and_walks_between() -> None:
    parts, action, world = _session(style_seed=3, seed=10)
    for name, minutes in ASKED.items():
        assert np.count_nonzero(action == ACTIONS.index(name)) / 16.0 >= 60.0 * minutes
    assert set(np.unique(action)) <= {NO_ACTION, STANDING, *map(ACTIONS.index, ASKED)}
    kinds = [p.item.kind for p in parts]
    assert kinds[0] == "stand"
    assert kinds[-1] == "stand"
    sets = [i for i, k in enumerate(kinds) if k == "set"]
    assert len(sets) >= len(ASKED) * 2  # minutes cut into sets
    for a, b in itertools.pairwise(sets):
        between = kinds[a + 1 : b]
        assert between == ["stand", "transition", "stand"]  # rest, walk, get ready
    for part in parts:
        labels = action[part.start : part.start + part.frames]
        if part.item.kind == "stand":
            assert (labels == STANDING).all()
        elif part.item.kind == "transition":
            assert (labels == NO_ACTION).all()
            assert part.frames > 16  # a real walk, more than a second
    assert sum(p.frames for p in parts if p.item.kind == "transition") > 10 * 16
    # Parts join without a jump: no keypoint moves more than 5 cm in 1/16 s anywhere.
    assert np.linalg.norm(np.diff(world, axis=0), axis=-1).max() < 0.5


def test_sets_come_in_an_order_of_their_own_for_each_person() -> None:
    orders = []
    for seed in (1, 2, 3):
        items = plan_session(ASKED, SET_S, REST_S, np.random.default_rng(seed))
        orders.append([i.action for i in items if i.kind == "set"])
    assert len({tuple(o) for o in orders}) == 3
    for order in orders:  # no action follows itself where that can be helped
        assert all(a != b for a, b in itertools.pairwise(order))
        assert sorted(set(order)) == sorted(ASKED)


def test_sets_are_cut_in_range_and_add_up() -> None:
    rng = np.random.default_rng(0)
    for seconds in (5.0, 40.0, 240.0, 241.5):
        sets = cut_sets(seconds, (30.0, 75.0), rng)
        assert sum(sets) == pytest.approx(seconds)
        if seconds >= 30.0:
            assert min(sets) >= 30.0 - 1e-9
            assert max(sets) <= 75.0 + 1e-9
    order = order_sets([("a", 1.0)] * 3 + [("b", 1.0)] * 3, np.random.default_rng(1))
    assert all(x[0] != y[0] for x, y in itertools.pairwise(order))


SESSION = """\
seed = 4
[subject]
height_m = 1.8
mass_kg = 80.0
style_seed = 6

[session]
actions = ["lunge", "in_place_walking"]
minutes_per_action = {lunge = 0.3, in_place_walking = 0.2}
set_s = [6.0, 10.0]
rest_s = [2.0, 4.0]
"""


def test_a_scene_asks_for_a_session_and_refuses_a_bad_one() -> None:
    scene = Scene.from_toml_text(SESSION, "lab.toml")
    motion = build_motion(scene)
    lunge = np.count_nonzero(motion.action == ACTIONS.index("lunge")) / motion.rate_hz
    marching = np.count_nonzero(motion.action == ACTIONS.index("in_place_walking"))
    assert lunge >= 18.0
    assert marching / motion.rate_hz >= 12.0
    assert build_motion(scene).world.tobytes() == motion.world.tobytes()  # repeatable
    bad = {
        "set_s = [6.0, 10.0]": "set_s = [10.0, 6.0]",
        "lunge = 0.3, ": "",
        'actions = ["lunge", "in_place_walking"]': 'actions = ["dance"]',
        "[session]": '[[script]]\naction = "squat"\nreps = 2\n\n[session]',
    }
    for old, new in bad.items():
        with pytest.raises(SceneError) as caught:
            Scene.from_toml_text(SESSION.replace(old, new), "lab.toml")
        assert str(caught.value).startswith("lab.toml")
        assert "\n" not in str(caught.value)
