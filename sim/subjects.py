"""A population of subjects for a corpus: heights, masses and styles from a seed.

Both sexes in equal numbers on average. Stature is normal per sex (adult
means and spreads in the range of national surveys, e.g. NCD-RisC 2016:
men about 1.76 +- 0.07 m, women about 1.63 +- 0.065 m), kept within
1.50-1.95 m; mass from a body-mass index drawn around 24.5 +- 3.5 kg/m^2,
kept within 18-35; foot length 0.152 x height (Drillis and Contini) with a
small individual spread, a little shorter in proportion for women. How each
person moves (walking speed, step length and width, toe-out, strike
pattern, depth and tempo of squats and lunges, ...) is drawn from their
``style_seed``, with the sources, in ``scotti.sim.traits``.

``trait_spread`` reports what a fixed population of drawn subjects looks
like, trait by trait, beside the range each is drawn from (numbers only).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
from scotti.sim.motion import Subject
from scotti.sim.skeleton import FOOT_LENGTH
from scotti.sim.traits import POPULATION_RANGES, STRIKE_SHARES, STRIKES, TraitRange

HEIGHT_RANGE_M: Final = (1.50, 1.95)
BMI_RANGE: Final = (18.0, 35.0)
_STATURE: Final = {"male": (1.76, 0.07), "female": (1.63, 0.065)}
_FOOT_SHARE: Final = {"male": 1.01, "female": 0.985}  # of 0.152 x height
# The population ``trait_spread`` describes by default.
SPREAD_SUBJECTS: Final = 500
SPREAD_SEED: Final = 2026
# Body traits drawn here (not from the style seed), with their sources.
BODY_RANGES: Final = {
    "height_m": TraitRange("m", *HEIGHT_RANGE_M, "NCD-RisC 2016: 1.63 (F) / 1.76 (M) m"),
    "bmi": TraitRange("kg/m^2", *BMI_RANGE, "our choice: 24.5 +- 3.5"),
    "foot_length_ratio": TraitRange("x height", 0.135, 0.17, "Drillis & Contini: 0.152"),
}


def draw_subjects(count: int, seed: int) -> list[Subject]:
    """``count`` subjects drawn from ``seed``; the same seed gives the same people."""
    if count < 0:
        msg = f"count must be >= 0, got {count}"
        raise ValueError(msg)
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x5B7]))
    subjects = []
    for _ in range(count):
        sex = "female" if rng.random() < 0.5 else "male"
        mean, spread = _STATURE[sex]
        height = float(np.clip(rng.normal(mean, spread), *HEIGHT_RANGE_M))
        bmi = float(np.clip(rng.normal(24.5, 3.5), *BMI_RANGE))
        foot = (
            FOOT_LENGTH
            * height
            * _FOOT_SHARE[sex]
            * float(np.clip(rng.normal(1, 0.03), 0.92, 1.08))
        )
        subjects.append(
            Subject(
                height_m=round(height, 3),
                mass_kg=round(bmi * height**2, 1),
                style_seed=int(rng.integers(0, 2**31 - 1)),
                foot_length_m=round(foot, 4),
            )
        )
    return subjects


@dataclass(frozen=True)
class TraitSpread:
    """How one trait came out over a population, beside the range it is drawn in."""

    name: str
    drawn_in: TraitRange  # unit, range kept in, literature source
    minimum: float
    p5: float
    mean: float
    p95: float
    maximum: float


@dataclass(frozen=True)
class PopulationSpread:
    """Every drawn trait's spread, and the strike patterns' shares (drawn and aimed at)."""

    subjects: int
    seed: int
    traits: tuple[TraitSpread, ...]
    strike_shares: dict[str, float]
    strike_shares_aimed: dict[str, float]


def trait_spread(count: int = SPREAD_SUBJECTS, seed: int = SPREAD_SEED) -> PopulationSpread:
    """The spread of every drawn trait over ``draw_subjects(count, seed)`` (no I/O)."""
    subjects = draw_subjects(count, seed)
    if not subjects:
        msg = "trait_spread needs at least one subject"
        raise ValueError(msg)
    columns: dict[str, tuple[TraitRange, list[float]]] = {
        "height_m": (BODY_RANGES["height_m"], [s.height_m for s in subjects]),
        "bmi": (BODY_RANGES["bmi"], [s.mass_kg / s.height_m**2 for s in subjects]),
        "foot_length_ratio": (
            BODY_RANGES["foot_length_ratio"],
            [s.foot_length / s.height_m for s in subjects],
        ),
    }
    for name, drawn_in in POPULATION_RANGES.items():
        columns[name] = (drawn_in, [float(getattr(s.traits, name)) for s in subjects])
    spreads = []
    for name, (drawn_in, raw) in columns.items():
        values = np.asarray(raw, dtype=np.float64)
        p5, p95 = np.percentile(values, [5, 95])
        spreads.append(
            TraitSpread(
                name,
                drawn_in,
                float(values.min()),
                float(p5),
                float(values.mean()),
                float(p95),
                float(values.max()),
            )
        )
    strikes = [s.traits.strike for s in subjects]
    return PopulationSpread(
        subjects=len(subjects),
        seed=seed,
        traits=tuple(spreads),
        strike_shares={k: strikes.count(k) / len(strikes) for k in STRIKES},
        strike_shares_aimed=dict(zip(STRIKES, STRIKE_SHARES, strict=True)),
    )
