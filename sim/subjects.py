"""A population of subjects for a corpus: heights, masses and styles from a seed.

Both sexes in equal numbers on average. Stature is normal per sex (adult
means and spreads in the range of national surveys, e.g. NCD-RisC 2016:
men about 1.76 +- 0.07 m, women about 1.63 +- 0.065 m), kept within
1.50-1.95 m; mass from a body-mass index drawn around 24.5 +- 3.5 kg/m^2,
kept within 18-35; foot length 0.152 x height (Drillis and Contini) with a
small individual spread, a little shorter in proportion for women.
"""

from __future__ import annotations

from typing import Final

import numpy as np
from scotti.sim.motion import Subject
from scotti.sim.skeleton import FOOT_LENGTH

HEIGHT_RANGE_M: Final = (1.50, 1.95)
BMI_RANGE: Final = (18.0, 35.0)
_STATURE: Final = {"male": (1.76, 0.07), "female": (1.63, 0.065)}
_FOOT_SHARE: Final = {"male": 1.01, "female": 0.985}  # of 0.152 x height


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
