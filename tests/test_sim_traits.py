"""People who differ: traits drawn in their ranges, repeatable, given ones kept, the spread."""

from __future__ import annotations

import numpy as np
import pytest
from scotti.sim.motion import Subject
from scotti.sim.scene import Scene, SceneError
from scotti.sim.subjects import BODY_RANGES, draw_subjects, trait_spread
from scotti.sim.traits import POPULATION_RANGES, STRIKES, TRAIT_NAMES, TRAIT_RANGES


def test_drawn_traits_lie_in_their_ranges_and_differ_between_people() -> None:
    subjects = draw_subjects(300, seed=4)
    for name, drawn_in in TRAIT_RANGES.items():
        values = np.array([getattr(s.traits, name) for s in subjects])
        assert drawn_in.low <= values.min(), name
        assert values.max() <= drawn_in.high, name
        population = POPULATION_RANGES[name]
        assert population.low <= values.min(), name
        assert values.max() <= population.high, name
        if population.high == population.low:  # push_off: not drawn, the typical walker's
            continue
        # Not one value for everybody: at least a fifth of the range is used.
        assert np.ptp(values) > 0.2 * (drawn_in.high - drawn_in.low), name
    assert {s.traits.push_off for s in subjects} == {1.0}
    strikes = [s.traits.strike for s in subjects]
    assert set(strikes) == set(STRIKES)
    assert strikes.count("heel") > 0.75 * len(strikes)  # mostly rearfoot
    # Walking speed is step length x cadence.
    for s in subjects[:20]:
        speed = s.step_length_m * s.cadence_spm / 60.0
        assert speed == pytest.approx(s.traits.walking_speed_mps)


def test_the_same_seed_gives_the_same_people() -> None:
    a, b = draw_subjects(20, seed=7), draw_subjects(20, seed=7)
    assert [s.traits for s in a] == [s.traits for s in b]
    other = draw_subjects(20, seed=8)
    assert [s.traits for s in other] != [s.traits for s in a]
    assert Subject(1.7, 60.0, style_seed=3).traits == Subject(1.7, 60.0, style_seed=3).traits


def test_a_given_trait_replaces_the_drawn_one_and_leaves_the_others() -> None:
    drawn = Subject(1.75, 70.0, style_seed=12)
    given = Subject(1.75, 70.0, style_seed=12, traits_given={"toe_out_deg": 15.0, "depth": 0.7})
    assert given.traits.toe_out_deg == 15.0
    assert given.depth == 0.7
    for name in TRAIT_NAMES:
        if name not in ("toe_out_deg", "depth"):
            assert getattr(given.traits, name) == getattr(drawn.traits, name), name
    header = given.as_dict()
    assert header["toe_out_deg"] == 15.0
    assert header["strike"] in STRIKES
    with pytest.raises(ValueError, match="unknown trait"):
        Subject(1.75, 70.0, traits_given={"toe_in": 3.0})


def test_cadence_follows_height_at_one_speed() -> None:
    same = {"walking_speed_mps": 1.3, "step_length_ratio": 0.42}
    short = Subject(1.55, 55.0, style_seed=1, traits_given=same)
    tall = Subject(1.90, 85.0, style_seed=1, traits_given=same)
    assert short.cadence_spm > tall.cadence_spm + 10.0
    assert short.step_length_m < tall.step_length_m


def test_a_scene_gives_traits_by_name_and_refuses_unknown_or_out_of_range_ones() -> None:
    text = """\
[subject]
height_m = 1.7
mass_kg = 60.0
strike = "forefoot"
cadence_spm = 118.0

[[script]]
action = "walking"
reps = 4
"""
    subject = Scene.from_toml_text(text).subject_model()
    assert subject.traits.strike == "forefoot"
    assert subject.cadence_spm == 118.0
    for bad, field in (("cadence_spm = 118.0", "cadence_spm = 300.0"), ("forefoot", "tiptoe")):
        with pytest.raises(SceneError) as caught:
            Scene.from_toml_text(text.replace(*((bad, field))), "p.toml")
        assert str(caught.value).startswith("p.toml line ")
    with pytest.raises(SceneError, match="toe_in"):
        Scene.from_toml_text(text.replace("cadence_spm = 118.0", "toe_in = 3"), "p.toml")


def test_trait_spread_reports_every_trait_over_a_fixed_population() -> None:
    spread = trait_spread(count=200, seed=5)
    names = [t.name for t in spread.traits]
    assert set(names) == set(TRAIT_RANGES) | set(BODY_RANGES)
    for t in spread.traits:
        assert t.minimum <= t.p5 <= t.p95 <= t.maximum, t.name
        assert t.minimum <= t.mean <= t.maximum, t.name
        # Drawn traits differ between people; push_off is the population's one value.
        assert t.minimum < t.maximum or t.drawn_in.low == t.drawn_in.high == t.mean, t.name
        assert t.drawn_in.source
    assert sum(spread.strike_shares.values()) == pytest.approx(1.0)
    assert spread.strike_shares["heel"] == pytest.approx(
        spread.strike_shares_aimed["heel"], abs=0.08
    )
    assert trait_spread(count=200, seed=5) == spread
