"""The corpus: one lab session per drawn subject; clean and realistic copies move alike."""

from __future__ import annotations

import numpy as np
from scotti.models.contract import ACTIONS
from scotti.sim.actions import EXERCISES
from scotti.sim.corpus import subject_scene
from scotti.sim.scene import build_motion
from scotti.sim.subjects import draw_subjects


def test_clean_and_realistic_copies_hold_the_same_motion_and_every_action() -> None:
    subject = draw_subjects(2, seed=9)[1]
    scenes = {
        effects: subject_scene(1, subject, corpus_seed=9, minutes_per_action=0.1, effects=effects)
        for effects in ("realistic", "none")
    }
    assert scenes["realistic"].effects
    assert not scenes["none"].effects
    assert scenes["realistic"].session is not None
    assert set(scenes["realistic"].session.actions) == set(EXERCISES)
    realistic, clean = (build_motion(s) for s in scenes.values())
    np.testing.assert_array_equal(realistic.world, clean.world)
    np.testing.assert_array_equal(realistic.action, clean.action)
    for action in EXERCISES:
        seconds = np.count_nonzero(clean.action == ACTIONS.index(action)) / clean.rate_hz
        assert seconds >= 6.0, action
    assert clean.subject.as_dict()["strike"] == subject.traits.strike
    # Another subject of the corpus is another person with another plan.
    other = build_motion(
        subject_scene(0, draw_subjects(2, seed=9)[0], corpus_seed=9, minutes_per_action=0.1,
                      effects="none")
    )  # fmt: skip
    assert len(other) != len(clean) or not np.array_equal(other.action, clean.action)


def test_a_mixed_corpus_has_clean_and_noisy_people_with_wide_insoles() -> None:
    people = draw_subjects(12, seed=9)
    scenes = [
        subject_scene(i, s, corpus_seed=9, minutes_per_action=0.1, effects="mixed", insoles="wide")
        for i, s in enumerate(people)
    ]
    clean = [not s.effects for s in scenes]
    assert 0 < sum(clean) < len(scenes)
    # A noisy person of the mixed corpus has the realistic corpus's draw, the same insole
    # spread choice aside.
    k = clean.index(False)
    realistic = subject_scene(k, people[k], corpus_seed=9, minutes_per_action=0.1,
                              effects="realistic", insoles="wide")  # fmt: skip
    assert scenes[k].effects == realistic.effects
    thresholds = [s.insole.resolved().threshold_kpa for s in scenes]
    assert max(thresholds) > 35  # beyond the typical draw's range
