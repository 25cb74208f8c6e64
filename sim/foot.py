"""A subject's foot: its shape (arch type, ball width) and where it sits on the insole.

Foot coordinates: ``s`` along the foot in metres from the back of the heel
(``s = length`` at the tip of the hallux) and ``t`` across it in metres from
the foot's long axis (heel centre to second toe), positive towards the
MEDIAL side. The same for both feet: the insoles send column 0 medial on
both, so a right and a left foot look alike in the data.

Shape, drawn per subject from published proportions:

- Arch type after Cavanagh and Rodgers (1987, J Biomech 20:547), who
  classified footprints by the arch index (midfoot contact area over the
  toe-less footprint area; quartiles of 107 adults): high <= 0.21,
  normal 0.21-0.26, flat >= 0.26, a quarter, a half and a quarter of
  people. The arch type sets how high the medial arch and the lateral
  column stand off the insole (``plantar.py``), so how much of the
  midfoot touches.
- Ball width (metatarsal breadth) as a share of foot length: about
  0.37-0.38 in adults of both sexes, SD about 0.018 (ANSUR II, Gordon et
  al. 2014: foot breadth about 101 of 270 mm in men, 92 of 245 mm in women).

Placement, where the foot lies on the insole: an offset along and across
and a small rotation (positive: toes turned laterally). Part of it belongs
to the person (how they wear their shoes), part is redrawn each time the
shoe goes on (per session): a few millimetres and degrees.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Final, Literal

import numpy as np

ArchType = Literal["high", "normal", "flat"]
ARCH_TYPES: Final[tuple[ArchType, ...]] = ("high", "normal", "flat")
# Population shares of the arch types (Cavanagh and Rodgers 1987 used quartiles).
_ARCH_SHARE: Final = (0.25, 0.50, 0.25)
# Height of the medial arch's soft tissue above the insole, foot unloaded and
# flat (mm), drawn uniformly per type; calibrated so that the quiet-standing
# footprint's arch index falls in the type's band (tests/test_sim_foot.py).
ARCH_HEIGHT_MM: Final[dict[ArchType, tuple[float, float]]] = {
    "high": (21.0, 26.0),
    "normal": (12.5, 16.0),
    "flat": (3.0, 9.0),
}
# Ball width / foot length (ANSUR II, Gordon et al. 2014).
BALL_WIDTH_MEAN: Final = 0.375
BALL_WIDTH_SD: Final = 0.018
BALL_WIDTH_RANGE: Final = (0.33, 0.42)
# Placement spreads (SD): per person, and the extra redraw per donning.
_ALONG_SD_MM: Final = (3.0, 1.5)
_ACROSS_SD_MM: Final = (2.5, 1.2)
_ROTATION_SD_DEG: Final = (2.0, 1.0)
# Gap between the back of the heel and the insole's heel end, mean placement.
HEEL_GAP_MM: Final = 4.0


@dataclass(frozen=True)
class FootShape:
    """One person's foot (both feet alike)."""

    length_m: float
    arch: ArchType = "normal"
    arch_height_mm: float = 14.0
    ball_width_ratio: float = BALL_WIDTH_MEAN

    @property
    def ball_width_m(self) -> float:
        return self.ball_width_ratio * self.length_m

    def as_dict(self) -> dict[str, float | str]:
        return dict(asdict(self))


@dataclass(frozen=True)
class Placement:
    """Where one foot lies on its insole, relative to the nominal fit.

    ``along_mm``: towards the toe end; ``across_mm``: towards the medial
    edge; ``rotation_deg``: toes turned laterally (toe-out inside the shoe).
    """

    along_mm: float = 0.0
    across_mm: float = 0.0
    rotation_deg: float = 0.0

    def as_dict(self) -> dict[str, float]:
        return dict(asdict(self))


CENTRED: Final = (Placement(), Placement())


@dataclass(frozen=True)
class Feet:
    """The shape of a subject's feet and where each lies on its insole (left, right)."""

    shape: FootShape
    placement: tuple[Placement, Placement] = CENTRED

    def as_dict(self) -> dict[str, object]:
        """For the session header's subject."""
        return {
            **self.shape.as_dict(),
            "placement": {
                "left": self.placement[0].as_dict(),
                "right": self.placement[1].as_dict(),
            },
        }


def draw_shape(
    length_m: float,
    subject_seed: int,
    arch: ArchType | None = None,
    ball_width_ratio: float | None = None,
) -> FootShape:
    """A subject's foot shape; what is given is kept, the rest drawn from ``subject_seed``."""
    rng = np.random.default_rng(np.random.SeedSequence([subject_seed, 0xF007]))
    drawn_arch: ArchType = ARCH_TYPES[int(rng.choice(3, p=_ARCH_SHARE))]
    unit = float(rng.random())
    width = float(np.clip(rng.normal(BALL_WIDTH_MEAN, BALL_WIDTH_SD), *BALL_WIDTH_RANGE))
    kind = drawn_arch if arch is None else arch
    lo, hi = ARCH_HEIGHT_MM[kind]
    return FootShape(
        length_m=float(length_m),
        arch=kind,
        arch_height_mm=round(lo + unit * (hi - lo), 2),
        ball_width_ratio=round(width if ball_width_ratio is None else ball_width_ratio, 4),
    )


def draw_placement(subject_seed: int, session_seed: int) -> tuple[Placement, Placement]:
    """Each foot's placement: the person's habit plus a small redraw per donning."""
    habit = np.random.default_rng(np.random.SeedSequence([subject_seed, 0x9A5E]))
    donning = np.random.default_rng(np.random.SeedSequence([subject_seed, session_seed, 0xD0FF]))
    out = []
    for _ in range(2):
        values = []
        for person_sd, donning_sd in (_ALONG_SD_MM, _ACROSS_SD_MM, _ROTATION_SD_DEG):
            value = habit.normal(0.0, person_sd) + donning.normal(0.0, donning_sd)
            values.append(round(float(np.clip(value, -3 * person_sd, 3 * person_sd)), 2))
        out.append(Placement(*values))
    return out[0], out[1]


def draw_feet(
    length_m: float,
    subject_seed: int,
    session_seed: int,
    arch: ArchType | None = None,
    ball_width_ratio: float | None = None,
) -> Feet:
    """Shape and placement of a subject's feet for one session, reproducibly."""
    return Feet(
        draw_shape(length_m, subject_seed, arch, ball_width_ratio),
        draw_placement(subject_seed, session_seed),
    )


def neutral_feet(length_m: float) -> Feet:
    """A normal-arched foot of mean width, centred on the insole (tests, defaults)."""
    return Feet(FootShape(length_m))


def foot_coordinates(
    along_m: np.ndarray,
    medial_m: np.ndarray,
    placement: Placement,
) -> tuple[np.ndarray, np.ndarray]:
    """Insole points -> foot coordinates (s, t) in metres.

    ``along_m`` from the insole's heel end, ``medial_m`` from its centre line
    towards the medial edge. The nominal fit puts the back of the heel
    ``HEEL_GAP_MM`` from the heel end, the foot's axis on the centre line;
    the placement shifts it and turns it about the back of the heel.
    """
    x = along_m - (HEEL_GAP_MM + placement.along_mm) * 1e-3
    y = medial_m - placement.across_mm * 1e-3
    # Toes turned laterally: the foot's axis points to -medial; undo that turn.
    theta = np.deg2rad(placement.rotation_deg)
    c, s = np.cos(theta), np.sin(theta)
    return x * c - y * s, x * s + y * c
