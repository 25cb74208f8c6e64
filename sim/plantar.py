"""The sole of the foot as a height field with soft tissue, in foot coordinates.

The plantar surface is the lower envelope of a few soft bodies, each a
paraboloid cap ``h = h0 + depth * ((da / ra)^2 + (db / rb)^2)`` over the
normalised foot coordinates ``a = s / length`` (0 back of the heel, 1 tip of
the hallux) and ``b = t / (ball_width / 2)`` (+1 medial edge of the ball):

- the heel pad under the calcaneus, lowest of all with the metatarsal heads;
- the lateral column (cuboid, fifth metatarsal base) and the medial arch,
  standing off the insole by amounts that depend on the arch type;
- the five metatarsal heads along the oblique metatarsal line, as separate
  caps (so the forefoot print is a scalloped band, as on real insoles);
- the hallux and the four lesser toe pads, a few millimetres up (the toes'
  sulcus lifts them when the foot stands flat).

Geometry after plantar pressure maps and footprints (heel centre about
15 % of foot length, metatarsal heads 65-74 % from lateral to medial,
hallux pad about 90 %; e.g. the maps of Cavanagh et al. 1987, Foot Ankle
7:262, "Pressure distribution under symptom-free feet during barefoot
standing"). Each body has its own tissue stiffness
(Winkler modulus, kPa per mm of compression): heel pad and metatarsal fat
pads stiffest under load, the midfoot softer (effective values for a
shod foot on a thin insole; calibrated to the walking peak pressures and
load shares documented in sim/EFFECTS.md).

Only this module knows the anatomy; ``contact.py`` presses whatever it
describes into the insole.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
from scotti.sim.foot import FootShape

# Regions the load is reported in (index into REGION_NAMES).
REGION_NAMES: Final = ("heel", "midfoot", "metatarsals", "toes")
HEEL, MIDFOOT, METATARSALS, TOES = range(4)
# Height above which a point is not part of the sole (the foot's outline).
NO_CONTACT_MM: Final = 40.0


@dataclass(frozen=True)
class Body:
    """One soft body of the sole; positions normalised (a along, b across, + medial)."""

    name: str
    region: int
    a: float
    b: float
    ra: float
    rb: float
    depth_mm: float  # height gained at one radius from the centre
    h0_mm: float  # lowest point above the plantar plane
    stiffness: float  # kPa per mm of compression


# Lateral column standoff (mm) against the medial arch height (mm).
_ARCH_MM: Final = (3.0, 9.0, 12.5, 16.0, 21.0, 26.0)
_LATERAL_STANDOFF_MM: Final = (0.0, 1.7, 2.5, 3.3, 5.3, 6.8)


# The metatarsal heads, lateral (5th) to medial (1st): the metatarsal parabola.
_MTH: Final = (
    ("mth5", 0.655, -0.64, 1.4),
    ("mth4", 0.690, -0.34, 0.9),
    ("mth3", 0.715, -0.04, 0.4),
    ("mth2", 0.735, 0.26, 0.0),
    ("mth1", 0.725, 0.60, 0.2),
)
# Toe pads, hallux first.
_TOES: Final = (
    ("hallux", 0.905, 0.50, 0.060, 0.26, 1.0),
    ("toe2", 0.875, 0.14, 0.034, 0.13, 2.0),
    ("toe3", 0.850, -0.13, 0.032, 0.12, 2.2),
    ("toe4", 0.820, -0.36, 0.030, 0.11, 2.4),
    ("toe5", 0.785, -0.58, 0.028, 0.10, 2.8),
)
# Where the toes hinge (metatarsophalangeal joints): just distal to the heads.
MTP_A: Final = 0.76
# How much the toes follow the forefoot's pitch: 1 a rigid foot, 0 toes that
# stay flat on the insole while the heel rises (the MTP joints dorsiflex).
TOE_FOLLOW: Final = 0.5

# The centre of pressure a frame asks for, in normalised coordinates: along
# the foot it reaches from the back of the heel pad to the hallux; across it
# runs on the walking COP line (heel centre, lateral midfoot, between the
# first and second metatarsal heads, hallux) and rolls +-ROLL_REACH to the
# medial (+) or lateral (-) edge.
COP_REACH_A: Final = (0.08, 0.90)
_COP_LINE_A: Final = (0.0, 0.30, 0.55, 0.72, 0.92)
_COP_LINE_B: Final = (-0.05, -0.05, -0.15, 0.10, 0.45)
ROLL_REACH_B: Final = 0.30
# ... narrowing where the sole is narrow: the heel's back and the hallux.
_ROLL_TAPER_A: Final = (0.08, 0.2, 0.75, 0.90)
_ROLL_TAPER: Final = (0.5, 1.0, 1.0, 0.4)

_K_HEEL: Final = 24.0
_K_MIDFOOT: Final = 12.0
_K_LATERAL: Final = 8.0
_K_MTH: Final = 26.0
_K_TOE: Final = 20.0


def bodies(shape: FootShape) -> tuple[Body, ...]:
    """The soft bodies of this foot's sole."""
    arch = shape.arch_height_mm
    # The lateral column stands off about a fifth of the medial arch height:
    # it touches in normal feet under load, barely in high arches. Normal
    # arches sit half a millimetre lower than the straight line through the
    # flat and high ends, which gives them the 5-10 % midfoot share of
    # walking that in-shoe norms report (sim/REALISM.md).
    lateral = float(np.interp(arch, _ARCH_MM, _LATERAL_STANDOFF_MM))
    out = [
        Body("heel", HEEL, 0.155, -0.04, 0.14, 0.60, 8.0, 0.0, _K_HEEL),
        Body("lateral_column", MIDFOOT, 0.45, -0.52, 0.22, 0.36, 6.0, lateral, _K_LATERAL),
        Body("medial_arch", MIDFOOT, 0.46, 0.18, 0.17, 0.48, 9.0, arch, _K_MIDFOOT),
    ]
    out += [Body(name, METATARSALS, a, b, 0.055, 0.21, 7.0, h0, _K_MTH) for name, a, b, h0 in _MTH]
    out += [Body(name, TOES, a, b, ra, rb, 7.0, h0, _K_TOE) for name, a, b, ra, rb, h0 in _TOES]
    return tuple(out)


@dataclass(frozen=True)
class Sole:
    """The sole sampled at points: height (mm), stiffness (kPa/mm), region, pitch lever."""

    height_mm: np.ndarray
    stiffness: np.ndarray
    region: np.ndarray  # int, index into REGION_NAMES
    lever_m: np.ndarray  # how far the point moves down per radian of forefoot-down pitch


def sample_sole(shape: FootShape, s_m: np.ndarray, t_m: np.ndarray) -> Sole:
    """The sole under foot points (s, t) in metres (any shape, broadcast together)."""
    a = np.asarray(s_m, dtype=np.float64) / shape.length_m
    b = np.asarray(t_m, dtype=np.float64) / (0.5 * shape.ball_width_m)
    a, b = np.broadcast_arrays(a, b)
    all_bodies = bodies(shape)
    heights = np.stack(
        [
            body.h0_mm
            + body.depth_mm * (((a - body.a) / body.ra) ** 2 + ((b - body.b) / body.rb) ** 2)
            for body in all_bodies
        ]
    )
    lowest = np.argmin(heights, axis=0)
    height = np.take_along_axis(heights, lowest[None], axis=0)[0]
    height = np.where((a < 0.0) | (a > 1.0), NO_CONTACT_MM, np.minimum(height, NO_CONTACT_MM))
    stiffness = np.array([body.stiffness for body in all_bodies])[lowest]
    region = np.array([body.region for body in all_bodies])[lowest]
    # Toes hinge at the MTP joints: beyond them they follow the pitch only partly.
    lever_a = np.where(region == TOES, MTP_A + TOE_FOLLOW * (a - MTP_A), a)
    return Sole(height, stiffness, region, lever_a * shape.length_m)


def cop_target(
    shape: FootShape, cop_u: np.ndarray, cop_medial: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Foot coordinates (s, t) in metres of a requested COP (``FootLoads`` convention).

    ``cop_u``: 0 heel .. 1 toes, clipped to the reach; ``cop_medial``: -1
    lateral edge .. +1 medial edge.
    """
    a = np.clip(cop_u, *COP_REACH_A)
    reach = ROLL_REACH_B * np.interp(a, _ROLL_TAPER_A, _ROLL_TAPER)
    b = np.interp(a, _COP_LINE_A, _COP_LINE_B) + reach * np.clip(cop_medial, -1.0, 1.0)
    return a * shape.length_m, b * (0.5 * shape.ball_width_m)
