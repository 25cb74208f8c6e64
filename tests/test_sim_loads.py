"""Foot loads: the touch-down transient, the internal rate and the insole's sampling of it."""

from __future__ import annotations

import numpy as np
import pytest
from scotti.models.contract import FRAME_RATE_HZ
from scotti.sim.loads import (
    CONTACT_FULL_M,
    IMPACT_MASS_FOREFOOT,
    IMPACT_MASS_HEEL,
    IMPACT_S,
    G,
    foot_loads,
    impact_forces,
)
from scotti.sim.scene import PHYSICS_OVERSAMPLE, Scene, build_motion
from scotti.sim.writer import sim_input

RATE = 1024.0
MASS = 70.0


def _falling(speed: float, rate: float = RATE) -> np.ndarray:
    """(N,) height of a foot falling at ``speed`` onto the floor and staying there."""
    t = np.arange(int(0.3 * rate)) / rate
    return np.maximum(0.05 - speed * t, 0.0)


@pytest.mark.parametrize(
    ("heel_first", "share"), [(True, IMPACT_MASS_HEEL), (False, IMPACT_MASS_FOREFOOT)]
)
@pytest.mark.parametrize("speed", [0.3, 1.5])
def test_a_touch_down_carries_the_effective_mass_momentum(
    heel_first: bool, share: float, speed: float
) -> None:
    low = _falling(speed)
    other = low + 0.01  # the other end of the foot lands later
    heel, toe = (low, other) if heel_first else (other, low)
    force = impact_forces(
        np.c_[heel, np.full_like(heel, 1.0)], np.c_[toe, np.full_like(toe, 1.0)], RATE, MASS
    )
    assert force[:, 1].max() == 0.0  # the other foot never lands
    impulse = force[:, 0].sum() / RATE
    assert impulse == pytest.approx(share * MASS * speed, rel=0.05)
    assert force[:, 0].max() == pytest.approx(
        0.5 * np.pi * share * MASS * speed / IMPACT_S, rel=0.02
    )
    loaded = np.flatnonzero(force[:, 0] > 0)
    assert (loaded[-1] - loaded[0] + 1) / RATE == pytest.approx(IMPACT_S, abs=2 / RATE)
    landed = np.flatnonzero(low <= CONTACT_FULL_M)[0]
    assert loaded[0] == landed  # starts when the foot reaches the floor


def _jump_scene() -> Scene:
    return Scene.model_validate(
        {
            "seed": 2,
            "subject": {"height_m": 1.75, "mass_kg": MASS, "style_seed": 2},
            "script": [{"action": "jump", "reps": 2, "stand_s": 0.5}],
        }
    )


def test_the_insole_samples_the_loads_of_the_internal_rate_at_its_frame_times() -> None:
    motion = build_motion(_jump_scene(), PHYSICS_OVERSAMPLE)
    assert motion.rate_hz == PHYSICS_OVERSAMPLE * FRAME_RATE_HZ
    sim = sim_input(motion)
    inner = foot_loads(motion.world, motion.com, motion.rate_hz, MASS, motion.ground_z)
    frames = sim.loads()
    assert sim.rate_hz == FRAME_RATE_HZ
    assert len(frames.load_n) == len(sim.com) == len(sim.labels.action)
    np.testing.assert_array_equal(frames.load_n, inner.load_n[::PHYSICS_OVERSAMPLE])
    np.testing.assert_array_equal(frames.cop_u, inner.cop_u[::PHYSICS_OVERSAMPLE])
    assert frames.impact_n is not None
    # A second difference of 16 Hz kinematics misses the landing the internal rate resolves.
    coarse = build_motion(_jump_scene(), 1)
    at_16 = foot_loads(coarse.world, coarse.com, coarse.rate_hz, MASS, coarse.ground_z)
    bw = MASS * G
    assert inner.load_n.sum(axis=1).max() / bw >= 2.5
    assert at_16.load_n.sum(axis=1).max() < inner.load_n.sum(axis=1).max()


def test_loads_sum_to_body_weight_standing() -> None:
    scene = Scene.model_validate(
        {
            "subject": {"height_m": 1.7, "mass_kg": MASS},
            "script": [{"action": "squat", "reps": 1, "stand_s": 2.0}],
        }
    )
    motion = build_motion(scene, PHYSICS_OVERSAMPLE)
    loads = foot_loads(motion.world, motion.com, motion.rate_hz, MASS, motion.ground_z)
    still = slice(len(motion) - int(0.5 * motion.rate_hz), len(motion))
    np.testing.assert_allclose(loads.load_n[still].sum(axis=1), MASS * G, rtol=0.02)
    every = loads.every(4)
    np.testing.assert_array_equal(every.total_n, loads.total_n[::4])
