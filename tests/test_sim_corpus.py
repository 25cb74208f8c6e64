"""The corpus: one lab session per drawn subject; clean and realistic copies move alike."""

from __future__ import annotations

import numpy as np
from scotti.models.contract import ACTIONS
from scotti.sim.actions import EXERCISES
from scotti.sim.corpus import subject_scene
from scotti.sim.scene import Scene, build_motion
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


def test_wide_paces_draw_slow_walkers_and_leave_everything_else_as_it_was() -> None:
    people = draw_subjects(16, seed=9)
    typical = [
        subject_scene(i, s, corpus_seed=9, minutes_per_action=0.1, effects="none")
        for i, s in enumerate(people)
    ]
    wide = [
        subject_scene(i, s, corpus_seed=9, minutes_per_action=0.1, effects="none", paces="wide")
        for i, s in enumerate(people)
    ]
    for t, w in zip(typical, wide, strict=True):
        assert t.subject.walking_speed_mps is None  # the typical draw, as before
        assert w.seed == t.seed
        assert w.insole == t.insole
        assert w.subject.model_copy(update={"walking_speed_mps": None}) == t.subject
    speeds = np.array([w.subject.walking_speed_mps for w in wide], dtype=float)
    cadences = np.array([w.subject.subject().cadence_spm for w in wide])
    assert speeds.min() < 0.8
    assert speeds.max() > 1.2
    assert cadences.min() < 90.0  # slower than anyone the typical population draws
    drawn = np.array([t.subject.subject().cadence_spm for t in typical])
    assert drawn.min() >= 95.0


def _scenes(count: int, effects: str, **spread: str) -> tuple[list[Scene], list[Scene]]:
    """Corpus seed 9's first ``count`` people: their typical scenes and those drawn with
    ``spread`` (e.g. ``bodies="wide"``), person by person."""
    people = draw_subjects(count, seed=9)
    typical = [
        subject_scene(i, s, corpus_seed=9, minutes_per_action=0.1, effects=effects)  # type: ignore[arg-type]
        for i, s in enumerate(people)
    ]
    wide = [
        subject_scene(i, s, corpus_seed=9, minutes_per_action=0.1, effects=effects, **spread)  # type: ignore[arg-type]
        for i, s in enumerate(people)
    ]
    return typical, wide


def test_wide_bodies_cover_the_schemas_bodies_and_leave_everything_else_as_it_was() -> None:
    typical, wide = _scenes(64, "realistic", bodies="wide")
    body = {"height_m": None, "mass_kg": None, "foot_length_m": None}
    for t, w in zip(typical, wide, strict=True):
        assert (w.seed, w.insole, w.effects, w.session) == (t.seed, t.insole, t.effects, t.session)
        assert w.subject.style_seed == t.subject.style_seed
        assert w.subject.model_copy(update=body) == t.subject.model_copy(update=body)
    heights = np.array([w.subject.height_m for w in wide])
    masses = np.array([w.subject.mass_kg for w in wide])
    feet = np.array([w.subject.foot_length_m for w in wide], dtype=float)
    # Within the schema, and well past the typical adults (1.50-1.95 m, feet 0.2-0.3 m).
    assert heights.min() >= 1.2
    assert heights.max() <= 2.2
    assert masses.min() >= 30.0
    assert masses.max() <= 200.0
    assert feet.min() >= 0.15
    assert feet.max() <= 0.35
    assert heights.min() < 1.35
    assert heights.max() > 2.05
    assert feet.min() < 0.18
    assert feet.max() > 0.32
    assert masses.max() > 150.0
    typical_heights = np.array([t.subject.height_m for t in typical])
    assert typical_heights.min() >= 1.5  # the typical draw, as before


def test_wide_gaits_cover_push_off_and_touch_down_and_leave_everything_else_as_it_was() -> None:
    typical, wide = _scenes(64, "realistic", gaits="wide")
    gait = {"push_off": None, "strike_pitch_deg": None}
    for t, w in zip(typical, wide, strict=True):
        assert (w.seed, w.insole, w.effects, w.session) == (t.seed, t.insole, t.effects, t.session)
        assert w.subject.model_copy(update=gait) == t.subject
        assert t.subject.subject().traits.push_off == 1.0  # the typical walker, as before
    push = np.array([w.subject.push_off for w in wide], dtype=float)
    pitch = np.array([w.subject.strike_pitch_deg for w in wide], dtype=float)
    assert push.min() >= 0.15
    assert push.max() <= 1.0
    assert push.min() < 0.3  # shufflers
    assert push.max() > 0.85
    assert pitch.min() < -5.0  # toes first, flat and heel landings alike
    assert pitch.max() > 25.0
    assert (np.abs(pitch) < 5.0).any()


def test_the_smallest_and_largest_wide_bodies_move() -> None:
    """A child's body on the smallest insole and a 2.2 m one: the simulator takes both."""
    people = draw_subjects(64, seed=9)
    wide = [
        subject_scene(i, s, corpus_seed=9, minutes_per_action=0.05, effects="none", bodies="wide")
        for i, s in enumerate(people)
    ]
    for scene in (min(wide, key=lambda w: w.subject.height_m),
                  max(wide, key=lambda w: w.subject.height_m)):  # fmt: skip
        motion = build_motion(scene)
        assert np.isfinite(motion.world).all()
        assert motion.subject.height_m == scene.subject.height_m


def test_wide_effects_redraw_three_effects_and_leave_person_and_motion_as_they_were() -> None:
    realistic, wide = _scenes(24, "realistic")[0], _scenes(24, "wide")[0]
    for r, w in zip(realistic, wide, strict=True):
        assert (w.seed, w.insole, w.subject, w.session) == (r.seed, r.insole, r.subject, r.session)
        assert w.effects  # nobody is clean, where a third of a mixed corpus is
        before = {e["name"]: e for e in r.effects}
        changed = [e["name"] for e in w.effects if before.get(e["name"]) != e]
        assert len(changed) == 3, changed
    offsets = [e["offset_ms"] for w in wide for e in w.effects if e["name"] == "foot_offset"]
    assert max(abs(o) for o in offsets) > 100.0  # a realistic draw stays within 20 ms
