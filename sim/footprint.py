"""What the foot model makes of standing and walking: arch index, load shares, peaks.

The numbers in sim/EFFECTS.md ("The foot and the insole") come from::

    python -m scotti.sim.footprint

- :func:`arch_index` - the quiet-standing footprint's arch index after
  Cavanagh and Rodgers (1987): the toe-less footprint is cut into thirds
  along the foot; the index is the middle third's contact area over the
  whole. High arch <= 0.21 < normal < 0.26 <= flat.
- :func:`walking_stance` - one stance phase of walking as ``FootLoads``:
  the vertical force's double hump (about 1.1 body weights at loading
  response and at push-off, 0.75 at mid-stance) and the centre of pressure
  rolling from the heel (heel rocker, first ~10 % of stance) over the
  midfoot at mid-stance to the metatarsal heads for push-off and the
  hallux at toe-off (forefoot rocker), after the textbook picture of gait
  (Perry and Burnfield 2010, Gait Analysis, ch. 2 and 4).
- :func:`stance_shares` - each plantar region's share of the force-time
  integral over the stance, and the peak pressure per region.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
from scotti.sim.contact import Contact
from scotti.sim.foot import ARCH_HEIGHT_MM, ARCH_TYPES, Feet, FootShape
from scotti.sim.loads import FootLoads
from scotti.sim.plantar import NO_CONTACT_MM, REGION_NAMES, TOES, cop_target, sample_sole
from scotti.sim.pressure import PressureRenderer

# Stance: fraction of stance -> COP along the foot (0 heel .. 1 toes).
_COP_STANCE: Final = (0.0, 0.1, 0.3, 0.5, 0.65, 0.8, 0.9, 1.0)
_COP_U: Final = (0.08, 0.14, 0.30, 0.44, 0.58, 0.71, 0.78, 0.88)
# Quiet standing: each foot carries half the weight, COP ~40 % along the foot
# (the arch index's footprint and the standing shares).
_STANDING_COP_U: Final = 0.38
_FOOTPRINT_STEP_M: Final = 0.002


def walking_stance(frames: int = 160, body_weight_n: float = 700.0) -> FootLoads:
    """One stance phase of the left foot (the right one in the air), ``frames`` long."""
    tau = np.linspace(0.0, 1.0, frames)
    bw = (
        1.1 * np.exp(-(((tau - 0.25) / 0.12) ** 2))
        + 1.1 * np.exp(-(((tau - 0.75) / 0.12) ** 2))
        + 0.75 * np.exp(-(((tau - 0.5) / 0.15) ** 2))
    ) * np.sqrt(np.sin(np.pi * tau))
    load = np.stack([bw * body_weight_n, np.zeros(frames)], axis=1)
    cop_u = np.interp(tau, _COP_STANCE, _COP_U)
    return FootLoads(
        load_n=load,
        cop_u=np.stack([cop_u, cop_u], axis=1),
        cop_medial=np.zeros((frames, 2)),
        contact=(load > 0).astype(np.float64),
        total_n=load.sum(axis=1),
    )


def quiet_standing(frames: int = 4, load_n: float = 350.0) -> FootLoads:
    """Quiet standing on the left foot's half of a 700 N body: COP ~40 % along the foot."""
    load = np.zeros((frames, 2))
    load[:, 0] = load_n
    return FootLoads(
        load_n=load,
        cop_u=np.full((frames, 2), _STANDING_COP_U),
        cop_medial=np.zeros((frames, 2)),
        contact=(load > 0).astype(np.float64),
        total_n=load.sum(axis=1),
    )


@dataclass(frozen=True)
class StanceShares:
    """Per plantar region (REGION_NAMES order)."""

    share: np.ndarray  # share of the force-time integral, sums to 1
    peak_kpa: np.ndarray  # highest pressure on any taxel of the region


def stance_shares(renderer: PressureRenderer, loads: FootLoads, foot: int = 0) -> StanceShares:
    """Regions' shares of the force-time integral and their peak pressures, one foot."""
    kpa = renderer.kpa(loads)[:, foot].astype(np.float64)  # (n, 32, 22)
    region = renderer.region[foot]
    impulse = np.array([kpa[:, region == r].sum() for r in range(len(REGION_NAMES))])
    peak = np.array([kpa[:, region == r].max(initial=0.0) for r in range(len(REGION_NAMES))])
    return StanceShares(impulse / impulse.sum(), peak)


def arch_index(shape: FootShape, body_weight_n: float = 700.0) -> float:
    """Cavanagh and Rodgers' arch index of the quiet-standing footprint (fine grid)."""
    half = 0.6 * shape.ball_width_m
    s, t = np.meshgrid(
        np.arange(0.0, shape.length_m, _FOOTPRINT_STEP_M) + _FOOTPRINT_STEP_M / 2,
        np.arange(-half, half, _FOOTPRINT_STEP_M) + _FOOTPRINT_STEP_M / 2,
        indexing="ij",
    )
    sole = sample_sole(shape, s, t)
    near = sole.height_mm < NO_CONTACT_MM
    contact = Contact(
        s[near],
        t[near],
        sole.height_mm[near],
        sole.stiffness[near],
        sole.lever_m[near],
        _FOOTPRINT_STEP_M**2,
    )
    s_t, t_t = cop_target(shape, np.array([_STANDING_COP_U]), np.zeros(1))
    load = np.array([body_weight_n / 2])
    x = contact.solve(load, s_t, t_t, iterations=40)
    touching = (contact.pressure(x, load)[0] > 0) & (sole.region[near] != TOES)
    along = s[near][touching]
    lo, third = along.min(), (along.max() - along.min()) / 3
    middle = (along >= lo + third) & (along < lo + 2 * third)
    return float(middle.sum() / touching.sum())


def main() -> None:
    """Print the table of sim/EFFECTS.md: per arch type, arch index, shares and peaks."""
    loads = walking_stance()
    length = 0.26
    print("walking stance, 700 N body weight, foot 0.26 m, centred, mean ball width")
    print(f"{'arch':>7} {'height':>6} {'AI':>5}  " + "  ".join(f"{n:>11}" for n in REGION_NAMES))
    for arch in ARCH_TYPES:
        lo, hi = ARCH_HEIGHT_MM[arch]
        for height in (lo, (lo + hi) / 2, hi):
            shape = FootShape(length, arch, height)
            shares = stance_shares(PressureRenderer(length, Feet(shape)), loads)
            cells = "  ".join(
                f"{100 * s:5.1f}% {p:3.0f}k"
                for s, p in zip(shares.share, shares.peak_kpa, strict=True)
            )
            print(f"{arch:>7} {height:5.1f}mm {arch_index(shape):5.3f}  {cells}")
    print("cells: share of the force-time integral, peak kPa on any taxel of the region")
    shape = FootShape(length, "normal", sum(ARCH_HEIGHT_MM["normal"]) / 2)
    standing = quiet_standing()
    shares = stance_shares(PressureRenderer(length, Feet(shape)), standing)
    cells = "  ".join(
        f"{100 * s:5.1f}% {p:3.0f}k" for s, p in zip(shares.share, shares.peak_kpa, strict=True)
    )
    print(f"quiet standing, 350 N, COP {_STANDING_COP_U:.2f}, normal arch: {cells}")


if __name__ == "__main__":
    main()
