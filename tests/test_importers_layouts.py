"""Discrete-cell layouts: where the cells land on our grid, and what their render keeps."""

from __future__ import annotations

import gzip
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest
from scotti.importers.errors import ImporterError, InputError
from scotti.importers.layout_fit import fit_force_areas, fit_positions, read_opengo_sides
from scotti.importers.layouts import (
    LAYOUT_DIR,
    CellLayout,
    CellRenderer,
    LayoutError,
    cell_means,
    known_layouts,
    layout,
)
from scotti.models.contract import FRAME_COLS, FRAME_ROWS
from scotti.models.insole import insole_mask

REALDATA = Path(__file__).resolve().parents[2] / "shared" / "realdata"
FEET = ("left", "right")
SHIPPED = ("gaitpdb-8", "moticon-opengo-16", "pedar-x-99")


def _cell(layout_: CellLayout, number: int) -> tuple[int, int]:
    """(row, column) of our grid under the centre of the vendor's cell ``number`` (1-based)."""
    along, across = layout_.centres[number - 1]
    return int(along * FRAME_ROWS), int(across * FRAME_COLS)


def test_the_three_vendor_layouts_are_shipped() -> None:
    assert known_layouts() == SHIPPED
    assert [layout(name).cells for name in SHIPPED] == [8, 16, 99]
    for name in SHIPPED:
        cells = layout(name)
        assert cells.name == name
        assert cells.source  # named, with its licence or its assumptions
        assert cells.foot == "left"


@pytest.mark.parametrize("name", SHIPPED)
@pytest.mark.parametrize("foot", FEET)
def test_each_cells_force_is_kept_on_our_grid(name: str, foot: str) -> None:
    cells = layout(name).for_foot(foot)  # type: ignore[arg-type]
    render = CellRenderer(cells)
    kpa = 150.0 * np.eye(cells.cells)  # one cell pressed at a time
    grid = render(kpa)
    assert grid.shape == (cells.cells, FRAME_ROWS, FRAME_COLS)
    force_grid = grid.sum(axis=(1, 2)) * cells.taxel_area_mm2 * 1e-3  # N
    force_cell = 150.0 * cells.areas_mm2 * 1e-3
    np.testing.assert_allclose(force_grid, force_cell, rtol=0.01)
    np.testing.assert_allclose(render.force_n(kpa), force_cell, rtol=1e-5)
    # Nothing lands outside our outline, and every cell reaches the grid.
    assert not grid[:, ~insole_mask()].any()
    assert (np.count_nonzero(grid.reshape(cells.cells, -1), axis=1) >= 1).all()


@pytest.mark.parametrize("name", SHIPPED)
def test_cell_centres_lie_inside_our_outline(name: str) -> None:
    cells = layout(name)
    rows, cols = (cells.centres * [FRAME_ROWS, FRAME_COLS]).astype(int).T
    outside = [i + 1 for i in np.flatnonzero(~insole_mask()[rows, cols])]
    assert outside == []


@pytest.mark.parametrize("foot", FEET)
def test_pedar_medial_cells_are_at_low_columns_and_the_heel_at_high_rows(foot: str) -> None:
    cells = layout("pedar-x-99").for_foot(foot)  # type: ignore[arg-type]
    # pressuRe's masks (pedar_mask3): hallux 83, 84, 90, 91, 96; first metatarsal
    # head 62, 63, 69, 70, 76, 77; fourth and fifth 60, 61, 67, 68, 74, 75.
    hallux = [_cell(cells, k) for k in (83, 84, 90, 91, 96)]
    mtpj1 = [_cell(cells, k) for k in (62, 63, 69, 70, 76, 77)]
    mtpj45 = [_cell(cells, k) for k in (60, 61, 67, 68, 74, 75)]
    assert max(c for _, c in hallux + mtpj1) < FRAME_COLS // 2
    assert min(c for _, c in mtpj45) > FRAME_COLS // 2
    assert min(r for r, _ in (_cell(cells, k) for k in range(1, 6))) >= FRAME_ROWS - 4  # heel row
    assert max(r for r, _ in (_cell(cells, k) for k in range(96, 100))) <= 2  # toe row
    assert max(r for r, _ in hallux) < min(r for r, _ in mtpj1)  # toes before the ball


@pytest.mark.parametrize("foot", FEET)
def test_moticon_and_gaitpdb_medial_sensors_are_at_low_columns(foot: str) -> None:
    moticon = layout("moticon-opengo-16").for_foot(foot)  # type: ignore[arg-type]
    assert _cell(moticon, 14)[1] < FRAME_COLS // 2  # the hallux sensor
    assert _cell(moticon, 7)[1] < FRAME_COLS // 2  # the arch sensor
    assert _cell(moticon, 13)[1] > FRAME_COLS // 2  # the fifth metatarsal head
    assert min(_cell(moticon, 1)[0], _cell(moticon, 2)[0]) > FRAME_ROWS * 3 // 4
    gait = layout("gaitpdb-8").for_foot(foot)  # type: ignore[arg-type]
    for medial, lateral in ((3, 2), (5, 4), (7, 6)):
        assert _cell(gait, medial)[1] < FRAME_COLS // 2 < _cell(gait, lateral)[1]
    assert _cell(gait, 1)[0] > FRAME_ROWS * 3 // 4
    assert _cell(gait, 8)[0] < FRAME_ROWS // 4


def test_a_right_insole_numbered_as_a_shifted_copy_swaps_medial_and_lateral(
    tmp_path: Path,
) -> None:
    text = (LAYOUT_DIR / "gaitpdb-8.toml").read_text()
    path = tmp_path / "shifted.toml"
    path.write_text(text.replace("right_mirrored = true", "right_mirrored = false"))
    left, mirrored = layout(str(path)), layout("gaitpdb-8")
    right = left.for_foot("right")
    np.testing.assert_allclose(right.centres[:, 1], 1.0 - left.centres[:, 1])
    np.testing.assert_allclose(right.centres[:, 0], left.centres[:, 0])
    np.testing.assert_allclose(right.for_foot("left").centres, left.centres)
    assert mirrored.for_foot("right").centres.tolist() == mirrored.centres.tolist()
    # Cells with outlines are fitted to our outline again after the swap.
    pedar = (LAYOUT_DIR / "pedar-x-99.toml").read_text()
    path.write_text(pedar.replace("right_mirrored = true", "right_mirrored = false"))
    left = layout(str(path))
    right = left.for_foot("right")
    assert _cell(right, 96)[1] > _cell(right, 99)[1]  # the left's hallux cell is lateral here
    render = CellRenderer(right)
    np.testing.assert_allclose(
        render(np.eye(99)).sum(axis=(1, 2)) * right.taxel_area_mm2, right.areas_mm2, rtol=0.01
    )


def _format_txt_positions(text: str) -> dict[str, tuple[float, float]]:
    rows = re.findall(r"^([LR][1-8])\s+(-?\d+)\s+(-?\d+)\s*$", text, flags=re.MULTILINE)
    return {name: (float(x), float(y)) for name, x, y in rows}


@pytest.mark.skipif(not (REALDATA / "physionet-gaitpdb").is_dir(), reason="no ../shared/realdata")
def test_gaitpdb_positions_are_format_txts() -> None:
    given = _format_txt_positions((REALDATA / "physionet-gaitpdb" / "format.txt").read_text())
    assert len(given) == 16
    with (LAYOUT_DIR / "gaitpdb-8.toml").open("rb") as f:
        shipped = tomllib.load(f)["cells"]["points"]
    assert [tuple(p) for p in shipped] == [given[f"L{k}"] for k in range(1, 9)]
    # The right insole is the left one mirrored about the mid-line between the
    # feet: its sensor k sits where the left's does, so one layout serves both.
    assert all(given[f"R{k}"] == (-given[f"L{k}"][0], given[f"L{k}"][1]) for k in range(1, 9))
    cells = layout("gaitpdb-8")
    along = cells.centres[:, 0]
    y = np.array([given[f"L{k}"][1] for k in range(1, 9)])
    np.testing.assert_allclose(along, 0.5 - y / 2000.0)  # Y -1000 .. 1000 from heel to toe
    # And the file's 8 forces add up to its total column: they stand for the foot.
    with gzip.open(REALDATA / "physionet-gaitpdb" / "GaCo01_01.txt.gz") as f:
        table = np.loadtxt(f)
    np.testing.assert_allclose(table[:, 1:9].sum(axis=1), table[:, 17], atol=0.05)


@pytest.mark.skipif(not (REALDATA / "moticon-opengo").is_dir(), reason="no ../shared/realdata")
def test_moticon_positions_and_areas_are_the_vendors_own() -> None:
    parts = [read_opengo_sides(p) for p in sorted((REALDATA / "moticon-opengo").glob("2309*.txt"))]
    assert {size for size, _ in parts} == {7}
    left = [sides["left"] for _, sides in parts]
    kpa = np.concatenate([s.kpa for s in left])
    areas, force_rms = fit_force_areas(kpa, np.concatenate([s.total_n for s in left]))
    positions, cop_rms = fit_positions(kpa, areas, np.concatenate([s.cop for s in left]))
    assert force_rms < 0.5
    assert cop_rms < 1e-4
    with (LAYOUT_DIR / "moticon-opengo-16.toml").open("rb") as f:
        shipped = tomllib.load(f)
    np.testing.assert_allclose(positions, shipped["cells"]["points"], atol=5e-4)
    np.testing.assert_allclose(areas, shipped["areas_mm2"]["7"], rtol=0.005)
    np.testing.assert_allclose(layout("moticon-opengo-16").areas_mm2, areas, rtol=0.005)


@pytest.mark.skipif(not (REALDATA / "pressure-r").is_dir(), reason="no ../shared/realdata")
@pytest.mark.parametrize("foot", FEET)
def test_pedar_recording_loads_the_lateral_midfoot_not_the_arch(foot: str) -> None:
    table = np.loadtxt(REALDATA / "pressure-r" / "pedar_example.asc", skiprows=10)
    kpa = table[:, 1:100] if foot == "left" else table[:, 100:199]  # cells 1..99 each
    render = CellRenderer(layout("pedar-x-99").for_foot(foot))  # type: ignore[arg-type]
    mean = render(kpa).mean(axis=0)
    # Behind the metatarsal heads (pressuRe's mid-foot masks: pedar rows 8 and 9).
    midfoot = mean[int(0.36 * FRAME_ROWS) : int(0.48 * FRAME_ROWS)]
    medial, lateral = midfoot[:, : FRAME_COLS // 3], midfoot[:, -FRAME_COLS // 3 :]
    assert medial.sum() < 0.6 * lateral.sum()


@pytest.mark.parametrize("name", SHIPPED)
def test_cell_means_of_a_uniform_map_and_of_a_rendered_one(name: str) -> None:
    cells = layout(name)
    render = CellRenderer(cells)
    uniform = np.where(insole_mask(), 120.0, 0.0)[None]
    np.testing.assert_allclose(render.cell_means(uniform), 120.0, rtol=1e-5)
    np.testing.assert_allclose(cell_means(cells, uniform), 120.0, rtol=1e-5)
    # A uniform load through the cells comes back as itself, times each cell's
    # area over what it covers here: 1 for tiles (sized to the areas); pedar's
    # drawn outlines and listed areas differ, and neighbours share edge taxels.
    back = render.cell_means(render(np.full((1, cells.cells), 80.0)))[0]
    factor = cells.areas_mm2 / (render.cell_taxels * cells.taxel_area_mm2)
    if cells.tiled:
        np.testing.assert_allclose(back, 80.0, rtol=0.01)
    else:
        assert np.median(np.abs(back / (80.0 * factor) - 1.0)) < 0.05
        assert factor.min() > 0.7
        assert factor.max() < 1.35


def test_unknown_names_and_sizes_are_one_line_errors() -> None:
    with pytest.raises(LayoutError) as err:
        layout("pedar-99")
    message = str(err.value)
    assert "\n" not in message
    assert "'pedar-99'" in message
    assert all(name in message for name in SHIPPED)
    assert isinstance(err.value, ImporterError)
    with pytest.raises(LayoutError, match=r"no size 'q' \(known: u, v, w, x, y, z, uw, xw, vw\)"):
        layout("pedar-x-99", size="q")
    with pytest.raises(LayoutError, match="has no insole sizes"):
        layout("gaitpdb-8", size="7")
    with pytest.raises(LayoutError, match=r"kpa must be \(N, 8\), not \(3, 9\)"):
        CellRenderer(layout("gaitpdb-8"))(np.zeros((3, 9)))


def test_sizes_change_areas_not_places() -> None:
    y, w = layout("pedar-x-99"), layout("pedar-x-99", size="w")
    assert (y.size, w.size) == ("y", "w")
    np.testing.assert_array_equal(y.centres, w.centres)
    assert w.areas_mm2.sum() < y.areas_mm2.sum()
    assert w.length_mm < y.length_mm
    # Moticon lists sizes 3 and 7; the others are extrapolated, and say so.
    small, five, big = (layout("moticon-opengo-16", size=s) for s in ("3", "5", "7"))
    assert small.areas_mm2.sum() < five.areas_mm2.sum() < big.areas_mm2.sum()
    assert "size 5 not listed" in five.source
    assert "not listed" not in big.source


def test_with_areas_keeps_the_map_and_scales_the_force() -> None:
    cells = layout("moticon-opengo-16")
    kpa = np.linspace(10.0, 300.0, 16)[None]
    doubled = cells.with_areas(2.0 * cells.areas_mm2, "doubled for the test")
    np.testing.assert_allclose(CellRenderer(doubled)(kpa), CellRenderer(cells)(kpa), rtol=1e-5)
    assert CellRenderer(doubled).force_n(kpa)[0] == pytest.approx(
        2.0 * CellRenderer(cells).force_n(kpa)[0], rel=1e-5
    )
    assert doubled.source.endswith("areas: doubled for the test")


def test_a_users_layout_file_renders_by_hand(tmp_path: Path) -> None:
    # Two cells splitting a rectangular insole at mid-length: toes and heel.
    path = tmp_path / "two.toml"
    path.write_text(
        'name = "two"\nsource = "a test"\n'
        '[frame]\ntoe = "-y"\nmedial = "+x"\n'  # the toes at small y, medial at large x
        "[cells]\noutlines = [[[0, 0], [10, 0], [10, 10], [0, 10]], "
        "[[0, 10], [10, 10], [10, 20], [0, 20]]]\n"
        "[areas_mm2]\none = [100.0, 100.0]\n"
    )
    cells = layout(str(path))
    np.testing.assert_allclose(cells.centres, [[0.25, 0.5], [0.75, 0.5]], atol=0.02)
    grid = CellRenderer(cells)(np.array([[100.0, 0.0]]))[0]
    assert grid[: FRAME_ROWS // 2][insole_mask()[: FRAME_ROWS // 2]].min() > 0
    assert not grid[FRAME_ROWS // 2 + 1 :].any()  # the heel cell carries nothing


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        ('name = "x"\nsource = "s"\n[frame]\ntoe = "+z"\n', "frame.toe: one of"),
        ('name = "x"\nsource = "s"\n[frame]\ntoe = "+y"\nmedial = "-y"\n', "different axes"),
        ('name = "x"\n[frame]\n', "source: a text is required"),
        ('name = "x"\nsource = "s"\n[frame]\ntoe = "+y"\nmedial = "+x"\n[cells]\n', "either"),
        ("name = ", "cannot read the layout"),
    ],
)
def test_a_bad_layout_file_is_one_line_naming_it(tmp_path: Path, text: str, problem: str) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(InputError) as err:
        layout(str(path))
    assert str(err.value).startswith(str(path))
    assert problem in str(err.value)
    assert "\n" not in str(err.value)


def test_the_layout_pictures_are_drawn(tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")
    from scotti.importers.pictures import main

    assert main(["--layouts", "-o", str(tmp_path)]) == 0
    drawn = sorted(p.name for p in tmp_path.iterdir())
    assert drawn == [f"layout-{name}.png" for name in SHIPPED]
    assert all((tmp_path / name).stat().st_size > 10_000 for name in drawn)
