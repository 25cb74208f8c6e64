"""How people differ: each movement trait, its published range, and how it is drawn.

A subject's traits are drawn from its ``style_seed`` (one generator, a fixed
order of draws, so giving one trait explicitly never changes the others).
Where a source gives a mean and a spread we draw a normal clipped to the
stated range; where it gives only a range we draw uniformly in it.

Walking (comfortable speed, healthy adults):

- speed 1.2-1.5 m/s: Bohannon 1997 (Age Ageing 26:15), comfortable gait
  speed 1.27-1.46 m/s by age decade and sex; drawn N(1.36, 0.10).
- step length 0.41-0.45 x height: Grieve and Gear 1966 (Ergonomics 9:379)
  relate stride length to stature (the pedometer rule of thumb is 0.413 x
  height for women, 0.415 for men); drawn N(0.415, 0.015) x height at the
  mean speed, scaled by the square root of the person's speed over it
  (faster walkers step both longer and quicker). Cadence follows from
  speed / step length (steps per minute), typically 100-125 steps/min
  (Grieve and Gear; Bohannon), kept within 95-135 (our limits, rarely
  reached); speed is recomputed when the clip bites.
  So at one speed taller people step longer and slower.
- slower walkers: many older people walk at 0.6-1.2 m/s (Studenski et al.
  2011, JAMA 305:50, gait speed and survival in older adults); the gaitpdb
  walkers of ../shared/realdata (people with Parkinson's disease and their
  controls) step 79-113 times a minute, a Moticon recording tagged "slow" 59.
  The population above never draws them; a given walking speed (a scene's,
  or a corpus drawn with ``--paces wide``) may go down to
  0.5 m/s, its step length then scaled down to 0.28 x height and its cadence
  down to 55 steps/min (the ranges of ``TRAIT_RANGES``; the population
  keeps the ``TYPICAL_*`` limits).
- step width (lateral distance between the feet's centres while walking)
  8-13 cm: Owings and Grabiner 2004 (J Biomech 37:935) and Helbostad and
  Moe-Nilssen 2003 (Gait Posture 17:27), about 0.10 +- 0.03 m; drawn
  N(0.10, 0.025) clipped 0.05-0.16.
- toe-out (foot progression angle) about 5-10 deg, SD ~5 deg: Seber et al.
  1981 (Acta Orthop Scand 52:559) and Staheli et al. 1985 (J Bone Joint
  Surg 67-A:39, adult mean ~10 deg, range -3..20); drawn N(7, 5) deg clipped
  -3..20, each foot a little different (N(0, 2) deg, right minus left).
- strike pattern: walking at comfortable speed nearly everyone lands heel
  first (Perry and Burnfield, Gait Analysis, 2nd ed., initial contact by
  the heel as the norm); we draw heel 88 %, midfoot 9 %, forefoot 3 %, our
  choice, shaped like Larson et al. 2011 (J Sports Sci 29:1665) for
  distance runners (88.9 % rearfoot, 3.4 % midfoot, 1.8 % forefoot), whose
  non-heel minority walking can only be smaller. Foot angle at contact:
  heel strike 20 +- 4 deg toes up (Perry and Burnfield; Winter 2009), flat
  0 +- 1 deg (heel and ball land together), forefoot 8 +- 3 deg toes down
  (our choice).
- stride-time variability (coefficient of variation) 1-3 %: Hausdorff 2005
  (J NeuroEng Rehabil 2:19); drawn N(0.02, 0.006) clipped 0.01-0.04.
- speed changes within a walk: slow drifts of a few per cent (our choice,
  amplitude N(0.05, 0.02) clipped 0.01-0.10).
- push-off: at toe-off the walking foot rolls over its toes, heel up, by
  0.6 rad (34 deg; 0.5 in a transition's steps) in the typical population,
  not drawn (``push_off`` = 1). Walkers who shuffle (Parkinson's disease,
  frailty) land flatter and push off less: reduced ankle push-off and heel
  rise are among the features of parkinsonian gait (Morris et al. 1994,
  Brain 117:1169, Svehlik et al. 2009, Arch Phys Med Rehabil 90:1880). A
  scene, or a corpus drawn with ``--gaits wide``, may scale that roll down to
  0.15 of it (our range); pedar's and GaPt03's real walks
  (docs/real-data.md) keep 70 % of the stance load on the heel half or land
  flat, as such walkers do.
- left/right asymmetry of step length and depth: a few per cent in healthy
  adults (Sadeghi et al. 2000, Gait Posture 12:34); drawn N(0, 0.025)
  clipped +-0.06 (right minus left share).

Standing: preferred stance width 17 cm between the heel centres (McIlroy
and Maki 1997, Clin Biomech 12:66, with about 14 deg between the feet);
drawn N(0.17, 0.03) m clipped 0.10-0.26.

Exercises (our choices where the literature gives no population range):

- squat depth 0.6-0.95 (1 = thighs a little past parallel), uniform;
  lunge depth N(0.8, 0.08) clipped 0.6-0.95.
- one self-paced bodyweight squat 2-4.5 s, N(3.0, 0.45); one lunge 2.6-5.2
  s, N(3.8, 0.5). Repetition-to-repetition spread of duration 2-7 % and of
  depth 2-10 %.
- pauses between repetitions: mean 0-1.5 s, uniform; each pause drawn
  exponential around it.
- fatigue over a set: repetitions slow down 2-8 % and get shallower 1-5 %
  per minute of the set (uniform; capped at 30 % and 20 %). Velocity loss
  within a set is the usual measure of fatigue (Sanchez-Medina and
  Gonzalez-Badillo 2011, Med Sci Sports Exerc 43:1725).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Final

import numpy as np

STRIKES: Final = ("heel", "midfoot", "forefoot")
STRIKE_SHARES: Final = (0.88, 0.09, 0.03)
# Foot pitch at touch-down by pattern (degrees, > 0 toes up): mean, SD.
STRIKE_PITCH_DEG: Final = {"heel": (20.0, 4.0), "midfoot": (0.0, 1.0), "forefoot": (-8.0, 3.0)}
Limits = tuple[float, float]
CADENCE_RANGE_SPM: Final = (55.0, 135.0)  # what a scene or a slow walker may have
TYPICAL_CADENCE_SPM: Final = (95.0, 135.0)  # the drawn population's limits; 100-125 is typical
TYPICAL_SPEED_MPS: Final = (1.05, 1.65)  # the drawn population's walking speeds
TYPICAL_STEP_RATIO: Final = (0.37, 0.47)  # the drawn population's step lengths (x height)
COMFORTABLE_SPEED_MPS: Final = 1.36  # the population's mean (Bohannon 1997)
PUSH_OFF_RANGE: Final = (0.15, 1.0)  # share of the typical toe-off roll; 1 for the population
FATIGUE_CAP: Final = (0.30, 0.20)  # largest slow-down and shallowing of a set


@dataclass(frozen=True)
class TraitRange:
    """One drawn trait: unit, the range it is kept in, and where the range comes from."""

    unit: str
    low: float
    high: float
    source: str


# The numeric traits, in the order they are drawn. Ranges are what a scene may
# give and what the draw is clipped to (or uniform over), but for walking speed,
# step length and cadence, whose draw keeps the typical population's narrower
# limits (POPULATION_RANGES below); ``source`` names the literature (see above).
TRAIT_RANGES: Final[dict[str, TraitRange]] = {
    "walking_speed_mps": TraitRange("m/s", 0.5, 1.65, "Bohannon 1997: 1.27-1.46; Studenski 2011"),
    "step_length_ratio": TraitRange("x height", 0.28, 0.47, "Grieve & Gear 1966: 0.41-0.45"),
    "step_width_m": TraitRange("m", 0.05, 0.16, "Owings & Grabiner 2004: 0.08-0.13 m"),
    "stance_width_m": TraitRange("m", 0.10, 0.26, "McIlroy & Maki 1997: 0.17 m"),
    "toe_out_deg": TraitRange("deg", -3.0, 20.0, "Seber 1981, Staheli 1985: 5-10 deg, SD 5"),
    "toe_out_asymmetry_deg": TraitRange("deg", -5.0, 5.0, "our choice: N(0, 2)"),
    "strike_pitch_deg": TraitRange("deg", -15.0, 30.0, "Perry & Burnfield: heel ~20 deg"),
    "stride_cv": TraitRange("", 0.01, 0.04, "Hausdorff 2005: 1-3 %"),
    "speed_variability": TraitRange("", 0.01, 0.10, "our choice"),
    "asymmetry": TraitRange("", -0.06, 0.06, "Sadeghi 2000: a few %"),
    "depth": TraitRange("", 0.6, 0.95, "our choice (squat)"),
    "lunge_depth": TraitRange("", 0.6, 0.95, "our choice"),
    "squat_rep_s": TraitRange("s", 2.0, 4.5, "our choice: self-paced"),
    "lunge_rep_s": TraitRange("s", 2.6, 5.2, "our choice: self-paced"),
    "tempo_variation": TraitRange("", 0.02, 0.07, "our choice"),
    "depth_variation": TraitRange("", 0.02, 0.10, "our choice"),
    "rep_pause_s": TraitRange("s", 0.0, 1.5, "our choice"),
    "fatigue_slowdown_per_min": TraitRange("/min", 0.02, 0.08, "Sanchez-Medina 2011"),
    "fatigue_shallowing_per_min": TraitRange("/min", 0.01, 0.05, "our choice"),
    "cadence_spm": TraitRange("steps/min", *CADENCE_RANGE_SPM, "Grieve & Gear: 100-125"),
    "push_off": TraitRange("x typical", *PUSH_OFF_RANGE, "our choice: shufflers to typical"),
}


# The ranges the drawn population keeps (sim/subjects.py trait_spread reports
# against these): TRAIT_RANGES but for the walking traits' typical limits.
POPULATION_RANGES: Final[dict[str, TraitRange]] = TRAIT_RANGES | {
    "walking_speed_mps": TraitRange("m/s", *TYPICAL_SPEED_MPS, "Bohannon 1997: 1.27-1.46 m/s"),
    "step_length_ratio": TraitRange(
        "x height", *TYPICAL_STEP_RATIO, "Grieve & Gear 1966: 0.41-0.45"
    ),
    "cadence_spm": TraitRange("steps/min", *TYPICAL_CADENCE_SPM, "Grieve & Gear: 100-125"),
    "push_off": TraitRange("x typical", 1.0, 1.0, "not drawn: the typical toe-off roll"),
}


@dataclass(frozen=True)
class Traits:
    """A person's movement style; every field is drawn unless given (see module doc)."""

    walking_speed_mps: float
    step_length_ratio: float
    step_width_m: float
    stance_width_m: float
    toe_out_deg: float
    toe_out_asymmetry_deg: float
    strike: str
    strike_pitch_deg: float
    stride_cv: float
    speed_variability: float
    asymmetry: float
    depth: float
    lunge_depth: float
    squat_rep_s: float
    lunge_rep_s: float
    tempo_variation: float
    depth_variation: float
    rep_pause_s: float
    fatigue_slowdown_per_min: float
    fatigue_shallowing_per_min: float
    cadence_spm: float
    push_off: float = 1.0  # share of the typical toe-off roll (not drawn: see the module doc)

    def toe_out_rad(self, side: int) -> float:
        """Toe-out of the left (0) or right (1) foot, radians."""
        half = 0.5 * self.toe_out_asymmetry_deg * (1.0 if side else -1.0)
        return math.radians(self.toe_out_deg + half)

    @property
    def strike_pitch_rad(self) -> float:
        return math.radians(self.strike_pitch_deg)

    def fatigue(self, elapsed_s: float) -> tuple[float, float]:
        """(slow-down, shallowing) shares after ``elapsed_s`` seconds of one set."""
        minutes = elapsed_s / 60.0
        return (
            min(self.fatigue_slowdown_per_min * minutes, FATIGUE_CAP[0]),
            min(self.fatigue_shallowing_per_min * minutes, FATIGUE_CAP[1]),
        )


TRAIT_NAMES: Final = tuple(f.name for f in fields(Traits))


def draw_traits(style_seed: int, height_m: float, given: Mapping[str, float | str]) -> Traits:
    """Traits of one person; ``given`` fixes some (by name), the rest come from the seed."""
    unknown = sorted(set(given) - set(TRAIT_NAMES))
    if unknown:
        msg = f"unknown trait(s) {', '.join(unknown)}; known: {', '.join(TRAIT_NAMES)}"
        raise ValueError(msg)
    rng = np.random.default_rng(style_seed)

    def normal(name: str, mean: float, sd: float, limits: Limits | None = None) -> float:
        r = TRAIT_RANGES[name]
        return float(np.clip(rng.normal(mean, sd), *(limits or (r.low, r.high))))

    def uniform(name: str) -> float:
        r = TRAIT_RANGES[name]
        return float(rng.uniform(r.low, r.high))

    # Every draw happens, in this order, whatever is given.
    drawn: dict[str, float | str] = {
        "walking_speed_mps": normal(
            "walking_speed_mps", COMFORTABLE_SPEED_MPS, 0.10, TYPICAL_SPEED_MPS
        ),
        "step_length_ratio": normal("step_length_ratio", 0.415, 0.015, TYPICAL_STEP_RATIO),
        "step_width_m": normal("step_width_m", 0.10, 0.025),
        "stance_width_m": normal("stance_width_m", 0.17, 0.03),
        "toe_out_deg": normal("toe_out_deg", 7.0, 5.0),
        "toe_out_asymmetry_deg": normal("toe_out_asymmetry_deg", 0.0, 2.0),
    }
    strike = STRIKES[int(rng.choice(len(STRIKES), p=STRIKE_SHARES))]
    pitch_draw = rng.standard_normal()
    drawn["strike"] = given.get("strike", strike)
    mean, sd = STRIKE_PITCH_DEG[str(drawn["strike"])]
    pitch_range = TRAIT_RANGES["strike_pitch_deg"]
    drawn["strike_pitch_deg"] = float(
        np.clip(mean + sd * pitch_draw, pitch_range.low, pitch_range.high)
    )
    drawn |= {
        "stride_cv": normal("stride_cv", 0.02, 0.006),
        "speed_variability": normal("speed_variability", 0.05, 0.02),
        "asymmetry": normal("asymmetry", 0.0, 0.025),
        "depth": uniform("depth"),
        "lunge_depth": normal("lunge_depth", 0.8, 0.08),
        "squat_rep_s": normal("squat_rep_s", 3.0, 0.45),
        "lunge_rep_s": normal("lunge_rep_s", 3.8, 0.5),
        "tempo_variation": uniform("tempo_variation"),
        "depth_variation": uniform("depth_variation"),
        "rep_pause_s": uniform("rep_pause_s"),
        "fatigue_slowdown_per_min": uniform("fatigue_slowdown_per_min"),
        "fatigue_shallowing_per_min": uniform("fatigue_shallowing_per_min"),
        "push_off": 1.0,  # not drawn (no generator call): earlier corpora remake byte for byte
    }
    values = {**drawn, **given}
    if values["strike"] not in STRIKES:
        msg = f"strike must be one of {', '.join(STRIKES)}, got {values['strike']!r}"
        raise ValueError(msg)
    # Faster walkers take longer steps as well as more of them: the step
    # length scales with the square root of the speed (about the usual
    # split of a speed change between the two), cadence = speed / step.
    # A drawn speed keeps the typical population's limits (so that corpora
    # drawn before slow walkers existed remake byte for byte); a given one
    # may be a slow walker's.
    slow = "walking_speed_mps" in given
    if "step_length_ratio" not in given:
        speed_share = float(values["walking_speed_mps"]) / COMFORTABLE_SPEED_MPS
        ratio = TRAIT_RANGES["step_length_ratio"]
        scaled = float(values["step_length_ratio"]) * speed_share**0.5
        limits = (ratio.low, ratio.high) if slow else TYPICAL_STEP_RATIO
        values["step_length_ratio"] = float(np.clip(scaled, *limits))
    step_m = float(values["step_length_ratio"]) * height_m
    if "cadence_spm" in given:
        cadence = float(given["cadence_spm"])
    else:
        limits = CADENCE_RANGE_SPM if slow else TYPICAL_CADENCE_SPM
        cadence = float(np.clip(60.0 * float(values["walking_speed_mps"]) / step_m, *limits))
    values["cadence_spm"] = cadence
    values["walking_speed_mps"] = cadence * step_m / 60.0  # a given cadence wins
    return Traits(**values)  # type: ignore[arg-type]
