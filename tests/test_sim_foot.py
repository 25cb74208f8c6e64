"""Feet: shapes drawn with published proportions, arch types by their footprints, placement."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from scotti.firmware_protocol.session import read_session
from scotti.sim.corpus import render_scene
from scotti.sim.foot import (
    ARCH_HEIGHT_MM,
    ARCH_TYPES,
    BALL_WIDTH_MEAN,
    FootShape,
    draw_feet,
    draw_placement,
    draw_shape,
)
from scotti.sim.footprint import arch_index
from scotti.sim.scene import Scene

# Cavanagh and Rodgers (1987): high <= 0.21 < normal < 0.26 <= flat.
AI_BANDS = {"high": (0.0, 0.21), "normal": (0.21, 0.26), "flat": (0.26, 1.0)}


def test_draws_repeat_from_the_seed_and_keep_what_is_given() -> None:
    assert draw_feet(0.26, 7, 1) == draw_feet(0.26, 7, 1)
    assert draw_shape(0.26, 7) != draw_shape(0.26, 8)
    given = draw_shape(0.26, 7, arch="flat", ball_width_ratio=0.4)
    assert (given.arch, given.ball_width_ratio) == ("flat", 0.4)
    lo, hi = ARCH_HEIGHT_MM["flat"]
    assert lo <= given.arch_height_mm <= hi


def test_population_of_arch_types_and_ball_widths() -> None:
    shapes = [draw_shape(0.26, seed) for seed in range(600)]
    kinds = Counter(s.arch for s in shapes)
    # quartiles of the arch index: a quarter high, half normal, a quarter flat
    assert 0.19 < kinds["high"] / 600 < 0.31
    assert 0.43 < kinds["normal"] / 600 < 0.57
    assert 0.19 < kinds["flat"] / 600 < 0.31
    ratios = np.array([s.ball_width_ratio for s in shapes])
    assert abs(ratios.mean() - BALL_WIDTH_MEAN) < 0.004
    assert 0.012 < ratios.std() < 0.024


@pytest.mark.parametrize("arch", ARCH_TYPES)
def test_standing_footprint_arch_index_matches_the_arch_type(arch: str) -> None:
    lo, hi = ARCH_HEIGHT_MM[arch]  # type: ignore[index]
    band_lo, band_hi = AI_BANDS[arch]
    for height in (lo, hi):
        for length, width in ((0.23, 0.34), (0.27, 0.41)):
            shape = FootShape(length, arch, height, width)  # type: ignore[arg-type]
            assert band_lo <= arch_index(shape) <= band_hi, (height, length, width)


def test_placement_is_a_habit_plus_a_small_redraw_per_donning() -> None:
    same_person = np.array(
        [[p.along_mm for p in draw_placement(3, session)] for session in range(200)]
    )
    people = np.array([[p.along_mm for p in draw_placement(person, 0)] for person in range(200)])
    assert same_person.std() < 0.7 * people.std()
    assert same_person.std() > 0.5  # yet each donning differs
    assert 1.5 < people.std() < 6.0  # millimetres
    rotation = np.array([[p.rotation_deg for p in draw_placement(k, 0)] for k in range(200)])
    assert 1.0 < rotation.std() < 4.0  # degrees


def test_rendered_scene_records_its_feet_and_insole(tmp_path: Path) -> None:
    scene = Scene.from_toml_text(
        """
seed = 4
[subject]
height_m = 1.7
mass_kg = 65.0
style_seed = 9
arch = "high"
[insole]
model = "ideal"
threshold_kpa = 2.0
[[script]]
action = "squat"
reps = 1
stand_s = 0.5
"""
    )
    render_scene(scene, tmp_path / "s.ses")
    header = read_session(tmp_path / "s.ses").header
    assert header.subject is not None
    assert header.scene is not None
    foot = header.subject["foot"]
    assert foot["arch"] == "high"
    expected = draw_feet(header.subject["foot_length_m"], 9, 4, arch="high").as_dict()
    assert foot == expected
    assert header.scene["insole"]["model"] == "ideal"
    assert header.scene["insole"]["threshold_kpa"] == 2.0
    assert header.scene["insole"]["gain_sigma"] == 0.0  # the ideal model's own value
