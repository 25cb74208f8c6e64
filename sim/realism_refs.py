"""What a biomechanist expects to see: the published ranges the simulator is held to.

One ``Reference`` per quantity, with the range and where it comes from. The
measurements that are compared against them live in
:mod:`scotti.sim.realism`; ``scotti sim realism`` puts both side by side in
sim/REALISM.md. A range is what the simulated figure must lie in; the source
says where the range comes from (and, where the literature gives a spread
rather than hard bounds, how the bounds were read off it).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final


@dataclass(frozen=True)
class Reference:
    """One quantity with its accepted range and its source."""

    key: str
    quantity: str
    low: float
    high: float
    unit: str
    source: str
    # The figure key of ``physics_figures.PhysicsFigures`` is ``key`` unless
    # ``figure`` names another; ``strike`` limits it to subjects of one strike pattern.
    figure: str | None = None
    strike: str | None = None
    arch: str | None = None
    # "every": each subject's value must lie in the range (ranges of individuals);
    # "median": the median over subjects must (the literature gives a population mean).
    judge: str = "every"

    @property
    def figure_key(self) -> str:
        return self.figure or self.key

    def applies_to(self, strike: str, arch: str) -> bool:
        """Whether a subject of this strike pattern and arch type is judged by this range."""
        return self.strike in (None, strike) and self.arch in (None, arch)

    def contains(self, value: float) -> bool:
        return self.low <= value <= self.high


_PERRY: Final = "Perry & Burnfield 2010, Gait Analysis, 2nd ed., ch. 19; Winter 2009, 4th ed."
_PUTTI: Final = (
    "Putti et al. 2007, Gait Posture 25:401 (in-shoe Pedar, regional load); "
    "Cavanagh et al. 1987, Foot Ankle 7:262"
)
_STRIKE_INDEX: Final = "Cavanagh & Lafortune 1980, J Biomech 13:397 (strike index thirds)"
_BOBBERT: Final = (
    "Bobbert, Huijing & van Ingen Schenau 1987, Med Sci Sports Exerc 19:332; "
    "McNitt-Gray 1993, J Biomech 26:1037"
)

REFERENCES: Final[tuple[Reference, ...]] = (
    # Forces, at the internal rate (before the 16 Hz insole samples them).
    Reference(
        "walking_first_peak_bw", "walking: first force peak per foot", 1.1, 1.3, "BW", _PERRY
    ),
    Reference(
        "walking_second_peak_bw", "walking: second force peak per foot", 1.1, 1.3, "BW", _PERRY
    ),
    Reference("walking_valley_bw", "walking: mid-stance valley per foot", 0.7, 0.8, "BW", _PERRY),
    Reference("jump_landing_peak_bw", "jump: landing peak, both feet", 2.5, 4.0, "BW", _BOBBERT),
    Reference("jump_flight_max_n", "jump: largest load in flight", 0.0, 0.0, "N", "physics"),
    Reference(
        "step_up_lead_peak_bw",
        "step-up: leading leg's peak",
        1.3,
        1.5,
        "BW",
        "Stacoff et al. 2005, Gait Posture 21:24 (stairs); raised for a 20 cm step exercise",
    ),
    # Where the load goes on the foot: walking, force-time integral per region
    # (heel strikers with normal arches, the population the in-shoe norms come
    # from: flat feet load the midfoot more, high arches less; a midfoot strike
    # spares the heel).
    Reference(
        "share_heel",
        "walking, heel strike, normal arch: heel share of the load",
        0.40,
        0.50,
        "",
        _PUTTI,
        arch="normal",
        strike="heel",
        judge="median",
    ),
    Reference(
        "share_midfoot",
        "walking, heel strike, normal arch: midfoot share",
        0.05,
        0.10,
        "",
        _PUTTI,
        arch="normal",
        strike="heel",
        judge="median",
    ),
    Reference(
        "share_metatarsals",
        "walking, heel strike, normal arch: metatarsal heads share",
        0.35,
        0.40,
        "",
        _PUTTI,
        arch="normal",
        strike="heel",
        judge="median",
    ),
    Reference(
        "share_toes",
        "walking, heel strike, normal arch: toes share",
        0.10,
        0.15,
        "",
        _PUTTI,
        arch="normal",
        strike="heel",
        judge="median",
    ),
    # Centre of pressure: where a stance starts and ends along the foot (0 heel, 1 toes).
    Reference(
        "walking_cop_onset_u",
        "walking, heel strikers: COP at touch-down",
        0.0,
        0.33,
        "u",
        _STRIKE_INDEX,
        strike="heel",
    ),
    Reference(
        "walking_cop_onset_u_midfoot",
        "walking, midfoot strikers: COP at touch-down",
        0.34,
        0.66,
        "u",
        _STRIKE_INDEX,
        figure="walking_cop_onset_u",
        strike="midfoot",
    ),
    Reference(
        "walking_cop_onset_u_forefoot",
        "walking, forefoot strikers: COP at touch-down",
        0.67,
        1.0,
        "u",
        _STRIKE_INDEX,
        figure="walking_cop_onset_u",
        strike="forefoot",
    ),
    Reference("walking_cop_offset_u", "walking: COP at toe-off", 0.7, 1.0, "u", _PERRY),
    Reference(
        "backward_cop_onset_u",
        "backward walking: COP at touch-down (toe first)",
        0.67,
        1.0,
        "u",
        "Grasso, Bianchi & Lacquaniti 1998, J Neurophysiol 80:1868; forefoot third of the strike"
        " index (Cavanagh & Lafortune 1980)",
    ),
    Reference(
        "backward_cop_offset_u",
        "backward walking: COP at lift-off (heel last)",
        0.0,
        0.3,
        "u",
        "Grasso, Bianchi & Lacquaniti 1998",
    ),
    Reference(
        "side_cop_with_travel",
        "side walking: share of the COP's sideways path going the way of travel",
        0.6,
        1.0,
        "",
        "weight moves onto the leading foot, then the trailing foot closes",
    ),
    Reference(
        "squat_cop_depth_correlation",
        "squat: correlation of the COP (along the foot) with depth",
        -1.0,
        -0.5,
        "r",
        "the hips go back as the knees flex: the COP moves toward the heel",
    ),
    Reference(
        "standing_com_ahead_m",
        "standing: COM in front of the ankles",
        0.04,
        0.06,
        "m",
        "Winter 1995, Gait Posture 3:193",
    ),
)

BY_KEY: Final = {r.key: r for r in REFERENCES}

# The phases of the gait cycle in steady level walking at a self-selected
# speed, healthy adults, as shares of the cycle (one stride): each foot
# stands ~60-62 % and swings ~38-40 %; both feet are down twice per cycle
# (loading response and pre-swing) for ~10-12 % each, ~20-24 % in all.
# Measured from rendered pressure frames (tests/test_sim_gait_phases.py,
# experiments/sim_walking_gait.py), not by ``scotti sim realism``.
_GAIT_CYCLE: Final = (
    "Perry & Burnfield 2010, Gait Analysis, 2nd ed., ch. 1 (stance 60 %, swing 40 %, "
    "two double supports of ~10 %); Whittle 2007, Gait Analysis: an Introduction, 4th ed., "
    "ch. 2 (stance ~60-62 %, double support ~10-12 % twice at self-selected speed)"
)
WALKING_PHASES: Final[tuple[Reference, ...]] = (
    Reference("walking_stance_share", "walking: stance per foot", 0.60, 0.62, "cycle", _GAIT_CYCLE),
    Reference("walking_swing_share", "walking: swing per foot", 0.38, 0.40, "cycle", _GAIT_CYCLE),
    Reference(
        "walking_double_support_share",
        "walking: both feet down, in all",
        0.20,
        0.24,
        "cycle",
        _GAIT_CYCLE,
    ),
)
