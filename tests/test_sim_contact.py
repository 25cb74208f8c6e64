"""The contact model: force and COP where asked, partial contact, load shares per arch type."""

from __future__ import annotations

import numpy as np
import pytest
from scotti.models.contract import FRAME_COLS, FRAME_ROWS
from scotti.sim.foot import ARCH_HEIGHT_MM, ArchType, Feet, FootShape, Placement
from scotti.sim.footprint import stance_shares, walking_stance
from scotti.sim.plantar import HEEL, METATARSALS, MIDFOOT, TOES
from scotti.sim.pressure import FootLoads, PressureRenderer

LENGTH_M = 0.26


def _loads(load_n: np.ndarray, cop_u: np.ndarray, cop_medial: np.ndarray) -> FootLoads:
    """Both feet the same frames."""
    both = np.stack([load_n, load_n], axis=1)
    return FootLoads(
        load_n=both,
        cop_u=np.stack([cop_u, cop_u], axis=1),
        cop_medial=np.stack([cop_medial, cop_medial], axis=1),
        contact=(both > 0).astype(np.float64),
        total_n=both.sum(axis=1),
    )


def _random_frames(n: int, seed: int) -> FootLoads:
    rng = np.random.default_rng(seed)
    return _loads(
        rng.uniform(30.0, 1500.0, n), rng.uniform(0.12, 0.86, n), rng.uniform(-0.8, 0.8, n)
    )


def _shape(arch: ArchType) -> FootShape:
    lo, hi = ARCH_HEIGHT_MM[arch]
    return FootShape(LENGTH_M, arch, (lo + hi) / 2)


@pytest.fixture(scope="module")
def placed() -> PressureRenderer:
    """A foot set off the insole's centre: the solver must follow the placement."""
    placements = (Placement(4.0, -3.0, 4.0), Placement(-2.0, 2.0, -3.0))
    return PressureRenderer(LENGTH_M, Feet(_shape("normal"), placements))


def test_no_load_presses_nothing(placed: PressureRenderer) -> None:
    kpa = placed.kpa(_loads(np.zeros(4), np.full(4, 0.5), np.zeros(4)))
    assert kpa.shape == (4, 2, FRAME_ROWS, FRAME_COLS)
    assert not kpa.any()


def test_the_map_carries_exactly_the_load(placed: PressureRenderer) -> None:
    loads = _random_frames(200, seed=1)
    newtons = placed.forces(loads).sum(axis=(2, 3))
    np.testing.assert_allclose(newtons, loads.load_n, rtol=1e-4)
    assert (placed.kpa(loads) >= 0).all()
    assert not placed.kpa(loads)[:, :, ~placed.mask].any()


def test_the_centre_of_pressure_is_where_the_loads_put_it(placed: PressureRenderer) -> None:
    loads = _random_frames(300, seed=2)
    force = placed.forces(loads).astype(np.float64)
    total = force.sum(axis=(2, 3))
    cop_s = (force * placed.s_m).sum(axis=(2, 3)) / total
    cop_t = (force * placed.t_m).sum(axis=(2, 3)) / total
    want_s, want_t = placed.cop_target(loads.cop_u, loads.cop_medial)
    assert np.abs(cop_s - want_s).max() < 0.004  # m: half a taxel row
    assert np.abs(cop_t - want_t).max() < 0.003
    # and it follows the request: forward along the foot, medial across it
    assert np.corrcoef(cop_s.ravel(), loads.cop_u.ravel())[0, 1] > 0.99
    _, neutral_t = placed.cop_target(loads.cop_u, np.zeros_like(loads.cop_u))
    assert np.corrcoef((cop_t - neutral_t).ravel(), loads.cop_medial.ravel())[0, 1] > 0.99


def test_contact_is_partial_and_grows_with_the_load() -> None:
    renderer = PressureRenderer(LENGTH_M, Feet(_shape("normal")))
    loads = _loads(np.array([20.0, 150.0, 700.0]), np.full(3, 0.42), np.zeros(3))
    touched = (renderer.kpa(loads)[:, 0] > 0).sum(axis=(1, 2))
    assert touched[0] < touched[1] < touched[2]
    assert touched[2] < 0.8 * renderer.mask.sum()  # never the whole insole: the arch stays off
    # light: (almost) only the lowest points, the heel pad and the metatarsal heads
    light = renderer.kpa(loads)[0, 0]
    region = renderer.region[0]
    lowest = light[(region == HEEL) | (region == METATARSALS)].sum()
    assert lowest > 0.95 * light.sum()
    assert not light[region == MIDFOOT].any()


def test_the_toes_touch_when_the_cop_goes_forward() -> None:
    renderer = PressureRenderer(LENGTH_M, Feet(_shape("normal")))
    kpa = renderer.kpa(_loads(np.full(2, 600.0), np.array([0.45, 0.85]), np.zeros(2)))[:, 0]
    toes = renderer.region[0] == TOES
    mid, forward = kpa[0][toes].sum() / kpa[0].sum(), kpa[1][toes].sum() / kpa[1].sum()
    assert mid < 0.12
    assert forward > 0.3
    assert forward > 3 * mid


@pytest.fixture(scope="module")
def shares() -> dict[str, np.ndarray]:
    """Stance load shares (heel, midfoot, metatarsals, toes) per arch type."""
    stance = walking_stance(frames=120)
    return {
        arch: stance_shares(PressureRenderer(LENGTH_M, Feet(_shape(arch))), stance).share
        for arch in ("flat", "normal", "high")
    }


# Walking, force-time integral over stance: heel ~45 %, midfoot 5-10 %,
# metatarsal heads 35-40 %, toes 10-15 % (normal arch). Flat feet move load
# onto the midfoot from heel and forefoot; high arches take it off.
@pytest.mark.parametrize(
    ("arch", "heel", "midfoot", "metatarsals", "toes"),
    [
        ("normal", (0.40, 0.50), (0.05, 0.10), (0.35, 0.40), (0.10, 0.15)),
        ("high", (0.40, 0.50), (0.005, 0.05), (0.35, 0.40), (0.10, 0.15)),
        ("flat", (0.38, 0.48), (0.10, 0.25), (0.28, 0.38), (0.10, 0.15)),
    ],
)
def test_walking_stance_load_shares(
    shares: dict[str, np.ndarray],
    arch: str,
    heel: tuple[float, float],
    midfoot: tuple[float, float],
    metatarsals: tuple[float, float],
    toes: tuple[float, float],
) -> None:
    got = shares[arch]
    for region, (lo, hi) in (
        (HEEL, heel),
        (MIDFOOT, midfoot),
        (METATARSALS, metatarsals),
        (TOES, toes),
    ):
        assert lo <= got[region] <= hi, (arch, region, got)


def test_midfoot_share_follows_the_arch(shares: dict[str, np.ndarray]) -> None:
    assert shares["flat"][MIDFOOT] > shares["normal"][MIDFOOT] > shares["high"][MIDFOOT]


def test_quiet_standing_loads_mostly_the_heel() -> None:
    """Cavanagh et al. 1987 (barefoot standing, 107 feet): heel 60.5 %, midfoot 7.8 %,
    forefoot 28.1 %, toes 3.6 % of the load; heel peak 139 kPa."""
    renderer = PressureRenderer(LENGTH_M, Feet(_shape("normal")))
    kpa = renderer.kpa(_loads(np.full(1, 350.0), np.full(1, 0.38), np.zeros(1)))[0, 0]
    share = [kpa[renderer.region[0] == r].sum() / kpa.sum() for r in range(4)]
    assert 0.50 < share[HEEL] < 0.68
    assert 0.03 < share[MIDFOOT] < 0.12
    assert 0.20 < share[METATARSALS] < 0.36
    assert share[TOES] < 0.08
    assert 100 < kpa[renderer.region[0] == HEEL].max() < 200


def test_walking_peak_pressures_are_plausible() -> None:
    """Heel and metatarsal heads 150-400 kPa walking (in-shoe to barefoot), midfoot far less."""
    renderer = PressureRenderer(LENGTH_M, Feet(_shape("normal")))
    peak = stance_shares(renderer, walking_stance(frames=120, body_weight_n=700.0)).peak_kpa
    assert 150 < peak[HEEL] < 400
    assert 150 < peak[METATARSALS] < 400
    assert peak[MIDFOOT] < 0.5 * min(peak[HEEL], peak[METATARSALS])


def test_placement_moves_the_map_on_the_grid() -> None:
    shape = _shape("normal")
    loads = _loads(np.full(1, 600.0), np.full(1, 0.42), np.zeros(1))

    def centroid(placement: Placement) -> np.ndarray:
        kpa = PressureRenderer(LENGTH_M, Feet(shape, (placement, placement))).kpa(loads)[0, 0]
        rows, cols = np.mgrid[0:FRAME_ROWS, 0:FRAME_COLS]
        return np.array([(kpa * rows).sum(), (kpa * cols).sum()]) / kpa.sum()

    home = centroid(Placement())
    forward = centroid(Placement(along_mm=16.0))  # two taxel rows towards the toes
    medial = centroid(Placement(across_mm=9.0))  # two columns towards column 0
    assert forward[0] == pytest.approx(home[0] - 2.0, abs=0.4)
    assert forward[1] == pytest.approx(home[1], abs=0.3)
    assert medial[1] == pytest.approx(home[1] - 2.0, abs=0.4)
    # toe-out: the forefoot swings laterally (to higher columns), the heel barely moves
    turned = PressureRenderer(LENGTH_M, Feet(shape, (Placement(rotation_deg=8.0),) * 2))
    straight = PressureRenderer(LENGTH_M, Feet(shape))
    front = _loads(np.full(1, 600.0), np.full(1, 0.72), np.zeros(1))
    cols = np.arange(FRAME_COLS)

    def col(renderer: PressureRenderer, loads: FootLoads) -> float:
        kpa = renderer.kpa(loads)[0, 0]
        return float((kpa.sum(axis=0) * cols).sum() / kpa.sum())

    assert col(turned, front) > col(straight, front) + 1.5
