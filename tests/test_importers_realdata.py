"""Every real recording in ../shared/realdata imports, and what can be checked holds.

The folder holds other people's recordings (its README names sources and
licences); these tests skip where it is absent (``SCOTTI_REALDATA`` points
elsewhere). What is checked against the source, counted here independently
of the readers: frames and rates; forces against body weight where it is
known, and against the file's own totals where it has them; left and right
not swapped (the arch is medial: the midfoot's medial half carries less than
its lateral half, and the big toe is medial); one-foot files flagged. The
last test runs on a committed 5 s cut of one gaitpdb file (tests/data/vendors)
and never skips.
"""

from __future__ import annotations

import gzip
import os
import re
from pathlib import Path

import numpy as np
import pytest
from scotti.cli.main import main
from scotti.firmware_protocol.session import read_session
from scotti.importers.layouts import CellRenderer, layout
from scotti.importers.vendors import read_vendor
from scotti.models.contract import FRAME_RATE_HZ
from scotti.models.input_checks import frame_stats
from scotti.models.insole import insole_mask

from tests.test_importers_vendors import session_feet

REALDATA = Path(
    os.environ.get("SCOTTI_REALDATA", Path(__file__).parents[2] / "shared" / "realdata")
)
FIXTURE = Path(__file__).parent / "data" / "vendors" / "GaCo01_01_first5s.txt"
G = 9.81
MIDFOOT = slice(14, 20)  # rows of our grid under the arch (row 0 at the toes)
TOES = slice(1, 6)
MEDIAL, LATERAL = slice(0, 11), slice(11, 22)  # column 0 medial on both feet

needs_realdata = pytest.mark.skipif(not REALDATA.is_dir(), reason=f"no {REALDATA}")


def real(name: str) -> Path:
    return REALDATA / name


def text_lines(path: Path) -> list[str]:
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rt", encoding="utf-8-sig", errors="replace") as f:
        return f.read().splitlines()


def imported(path: Path, tmp_path: Path, *extra: str) -> Path:
    out = tmp_path / f"{path.name}.scotti"
    assert main(["import", str(path), "-o", str(out), *extra]) == 0
    return out


def frames_at_16_hz(first_s: float, last_s: float) -> int:
    return int(np.floor((last_s - first_s) * FRAME_RATE_HZ + 1e-9)) + 1


def medial_signs(counts: np.ndarray) -> tuple[float, float]:
    """(lateral - medial of the midfoot, medial - lateral of the toes), mean counts a taxel."""
    mask = insole_mask()
    mean = counts.astype(np.float64).mean(axis=0)

    def half(rows: slice, cols: slice) -> float:
        return float(mean[rows, cols][mask[rows, cols]].mean())

    arch = half(MIDFOOT, LATERAL) - half(MIDFOOT, MEDIAL)
    toes = half(TOES, MEDIAL) - half(TOES, LATERAL)
    return arch, toes


def assert_not_swapped(
    feet: dict[str, np.ndarray], *, toes_tell: bool = True, each_foot: bool = True
) -> None:
    """Each foot shows its medial side where ours is (arch or big toe), and the arches agree.

    Swapping the feet puts each one's medial side on the lateral columns, so
    both signs of both feet would turn. One person's foot may have a flat
    arch or a lateral toe-off; both feet's arches together, and each foot's
    arch or toe, stay on the medial side. gaitpdb's one toe sensor sits on
    the mid-line: there the toes tell nothing. ``each_foot`` False: only
    both arches together (a patient's foot may roll medially).
    """
    signs = {foot: medial_signs(c) for foot, c in feet.items()}
    assert sum(arch for arch, _ in signs.values()) > 0, signs
    for foot, (arch, toes) in signs.items():
        assert not each_foot or arch > 0 or (toes_tell and toes > 0), (foot, signs)


# --- pedar: 99 cells, kPa, standing then walking --------------------------------


@needs_realdata
def test_pedar_frames_rate_standing_force_and_sides(tmp_path: Path) -> None:
    path = real("pressure-r/pedar_example.asc")
    lines = text_lines(path)
    start = next(i for i, line in enumerate(lines) if line.lstrip().startswith("time["))
    rows = [line for line in lines[start + 1 :] if line.strip()]
    times = np.array([float(r.split("\t")[0]) for r in rows])
    assert len(rows) == 1505  # "total time 15.050 s, time per frame 0.01 s"
    rec = read_vendor(path)
    assert rec.times_s.size == len(rows)
    assert rec.rate_hz == 100.0
    assert sorted(rec.feet) == ["left", "right"]
    out = imported(path, tmp_path)
    feet = session_feet(out)
    assert feet["left"].shape[0] == frames_at_16_hz(times[0], times[-1]) == 241
    # quiet standing for the first 2.5 s: both feet together steady, and what a walk's
    # whole strides carry on average (body weight) within 10 %
    force = sum(
        CellRenderer(layout("pedar-x-99", d.layout_size).for_foot(f)).force_n(d.values)  # type: ignore[arg-type]
        for f, d in rec.feet.items()
    )
    standing = force[rec.times_s < 2.5]
    walking = force[rec.times_s > 3.0]
    assert standing.std() < 0.03 * standing.mean()
    assert 400 < standing.mean() < 1300  # a person, in newtons
    assert abs(walking.mean() / standing.mean() - 1) < 0.10
    assert_not_swapped(feet)


# --- F-Scan: one foot, a 60 x 21 grid ---------------------------------------------


@needs_realdata
def test_fscan_one_foot_frames_rate_calibrated_force_and_flag(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = real("pressure-r/fscan_testL.asf")
    lines = text_lines(path)
    frame_lines = [line for line in lines if re.match(r"^Frame \d+$", line.strip())]
    assert len(frame_lines) == 205
    rec = read_vendor(path)
    assert rec.times_s.size == 205
    assert rec.rate_hz == pytest.approx(1 / 0.032)
    assert list(rec.feet) == ["left"]
    assert rec.info["foot"]["from"] == "outline"  # the file's name says L too
    assert rec.info["foot"]["name_says"] == "left"
    # calibrated on 75 kg: a walking foot's peak is 1.0 - 1.5 body weights
    data = rec.feet["left"]
    assert data.kpa_per_unit == 1.0
    assert data.mask is not None
    assert data.sensel_area_mm2 is not None
    newtons = (data.values * data.mask).sum(axis=(1, 2)) * data.sensel_area_mm2 * 1e-3
    assert 1.0 < newtons.max() / (75 * G) < 1.5
    out = imported(path, tmp_path)
    assert "right foot: absent from the file, no packets for it" in capsys.readouterr().out
    feet = session_feet(out)
    assert list(feet) == ["left"]
    assert feet["left"].shape[0] == frames_at_16_hz(0.0, 204 * 0.032)
    header = read_session(out).header.imported
    assert header is not None
    assert header["pressure"]["absent_feet"] == ["right"]
    assert_not_swapped(feet)


# --- XSENSOR: both feet in this file, 31 x 11, mmHg --------------------------------


@needs_realdata
def test_xsensor_frames_rate_units_against_its_own_load_and_sides(tmp_path: Path) -> None:
    path = real("pressure-r/xsensor_data.csv")
    lines = text_lines(path)
    assert sum(line.startswith("FRAME,") for line in lines) == 101
    sensors = [line.split(",")[1] for line in lines if line.startswith("SENSOR,")]
    assert {s.split()[0][-2:] for s in sensors} == {"LF", "RF"}  # both insoles, 101 each
    stamps = [line.split(",")[1].strip() for line in lines if line.startswith("Time,")]
    clock = np.array(
        [3600 * int(h) + 60 * int(m) + float(s) for h, m, s in (x.split(":") for x in stamps)]
    )
    rec = read_vendor(path)
    np.testing.assert_allclose(rec.times_s, clock - clock[0], atol=1e-9)
    assert rec.rate_hz == pytest.approx(100 / (clock[-1] - clock[0]))
    # mmHg x sensel area is the file's own "Est. Load (N)" of each insole
    for foot, data in rec.feet.items():
        assert data.kpa_per_unit is not None
        assert data.sensel_area_mm2 is not None
        assert data.total_force_n is not None
        newtons = data.values.sum(axis=(1, 2)) * data.kpa_per_unit * data.sensel_area_mm2 * 1e-3
        np.testing.assert_allclose(newtons, data.total_force_n, rtol=0.01, atol=0.5, err_msg=foot)
    out = imported(path, tmp_path)
    feet = session_feet(out)
    assert feet["left"].shape[0] == frames_at_16_hz(clock[0], clock[-1])
    assert_not_swapped(feet)


# --- Moticon OpenGo: 16 cells, N/cm², events ---------------------------------------


MOTICON = [
    "moticon-opengo/230927_102114.txt",
    "moticon-opengo/230927_102137.txt",
    "moticon-opengo/230927_102231.txt",
    "moticon-opengo/walk_data_with_events/text_export.txt",
]


@needs_realdata
@pytest.mark.parametrize("name", MOTICON)
def test_moticon_frames_rate_force_against_its_total_events_and_sides(
    name: str, tmp_path: Path
) -> None:
    path = real(name)
    lines = text_lines(path)
    names = next(x for x in lines if x.startswith("# time")).lstrip("# ").split("\t")
    marks = [i for i, n in enumerate(names) if n.endswith(("steps[]", " label[]"))]
    rows = [line.split("\t") for line in lines if line and not line.startswith("#")]
    times = np.array([float(r[0]) for r in rows])
    events = sum(1 for r in rows for i in marks if i < len(r) and r[i].strip())
    rec = read_vendor(path)
    assert rec.rate_hz == pytest.approx(100.0, abs=0.01)
    first, last = rec.info["cut_s"]
    assert rec.times_s[0] == pytest.approx(times[0] + first)
    assert rec.times_s[-1] == pytest.approx(times[-1] - last)
    assert first < 1.0  # at most the first second, while the later insole connects
    # N/cm² x the layout's areas is the file's own total force, frame by frame
    for foot, data in rec.feet.items():
        lay = layout("moticon-opengo-16", data.layout_size).for_foot(foot)  # type: ignore[arg-type]
        newtons = CellRenderer(lay).force_n(data.values * 10.0)
        assert data.total_force_n is not None
        np.testing.assert_allclose(newtons, data.total_force_n, atol=2.0, err_msg=foot)
    assert len(rec.events) == events > 0
    out = imported(path, tmp_path)
    header = read_session(out).header.imported
    assert header is not None
    assert len(header["events"]) == events
    tag = rec.info["header"].get("Tag")
    assert header["vendor"]["tags"] == ([tag] if tag else [])
    feet = session_feet(out)
    assert feet["left"].shape[0] == frames_at_16_hz(rec.times_s[0], rec.times_s[-1])
    assert_not_swapped(feet)


# --- gaitpdb: 8 force sensors a foot, newtons, body weight known ------------------


GAITPDB = sorted(p.name for p in (REALDATA / "physionet-gaitpdb").glob("*.txt.gz")) or ["none"]


def demographics() -> dict[str, dict[str, str]]:
    rows = [
        line.split("\t") for line in text_lines(REALDATA / "physionet-gaitpdb/demographics.txt")
    ]
    return {r[0]: dict(zip(rows[0], r, strict=False)) for r in rows[1:] if r and r[0]}


def check_gaitpdb(path: Path, tmp_path: Path, mass_kg: float | None) -> None:
    table = np.array(
        [[float(c) for c in line.split()] for line in text_lines(path) if line.strip()]
    )
    rec = read_vendor(path)
    assert rec.format == "gaitpdb"
    assert rec.times_s.size == table.shape[0]
    assert rec.rate_hz == 100.0
    assert (table.shape[0] - 1) / (table[-1, 0] - table[0, 0]) == pytest.approx(100.0, rel=1e-3)
    out = imported(path, tmp_path)
    feet = session_feet(out)
    n = frames_at_16_hz(table[0, 0], table[-1, 0])
    assert feet["left"].shape[0] == n
    force = frame_stats(np.concatenate([feet["left"], feet["right"]], axis=2)).force_n.sum(axis=1)
    file_total = table[:, 17] + table[:, 18]
    # each foot was scaled to the file's total: what the daemon reads back is it, less what
    # our count curve drops under its 20 kPa threshold
    assert 0.85 < force.mean() / file_total.mean() < 1.02
    if mass_kg is not None:  # over whole strides the feet carry the body's weight
        assert 0.6 < file_total.mean() / (mass_kg * G) < 1.6
        assert 0.6 < force.mean() / (mass_kg * G) < 1.6
    # JuPt01's right foot (Parkinson's disease) loads its medial midfoot more than its
    # lateral: for patients both feet's arches together, for controls each foot's
    assert_not_swapped(feet, toes_tell=False, each_foot="Pt" not in path.name)


@needs_realdata
@pytest.mark.parametrize("name", GAITPDB)
def test_gaitpdb_frames_rate_force_against_weight_and_sides(name: str, tmp_path: Path) -> None:
    subject = name.split("_")[0]
    weight = demographics()[subject].get("Weight", "NaN")
    mass = float(weight) if weight not in ("", "NaN") else None
    check_gaitpdb(REALDATA / "physionet-gaitpdb" / name, tmp_path, mass)
    header = read_session(tmp_path / f"{name}.scotti").header
    assert header.subject is not None
    assert header.subject.get("mass_kg") == mass  # from demographics.txt beside the file


def test_the_committed_gaitpdb_cut_imports_and_holds(tmp_path: Path) -> None:
    check_gaitpdb(FIXTURE, tmp_path, 83.0)  # GaCo01: 83 kg (tests/data/vendors/README.md)


# --- every file, no options ---------------------------------------------------------


@needs_realdata
def test_every_file_imports_with_no_options(tmp_path: Path) -> None:
    skip = {"README.md", "LICENSE", "format.txt", "demographics.txt"}
    files = [p for p in sorted(REALDATA.rglob("*")) if p.is_file() and p.name not in skip]
    assert len(files) >= 15
    for path in files:
        out = tmp_path / "x.scotti"
        assert main(["import", str(path), "-o", str(out), "--force"]) == 0, path
