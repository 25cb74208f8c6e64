"""Vendor exports (importers/vendors/): detection, reading, the import, one-foot files, mistakes.

Every file here is written by the test in the vendor's own layout
(tests/support/vendor_files.py); the real recordings are in
test_importers_realdata.py.
"""

from __future__ import annotations

import gzip
import re
from datetime import datetime
from pathlib import Path

import numpy as np
import pytest
from scotti.cli.main import main
from scotti.firmware_protocol.session import read_session
from scotti.importers.errors import InputError
from scotti.importers.layouts import CellRenderer, layout
from scotti.importers.vendors import detect, read_vendor
from scotti.importers.vendors.fscan import foot_from_outline
from scotti.models.input_checks import frame_stats
from scotti.models.insole import counts_from_kpa, insole_mask

from tests.support.vendor_files import (
    insole_outline,
    write_fscan,
    write_gaitpdb,
    write_moticon,
    write_pedar,
    write_xsensor,
)

RNG = np.random.default_rng(7)
OURS_AT_128_KPA = 1635  # 4095 q^0.8 / (q^0.8 + 180^0.8), q = 108 kPa (models/insole.py)


def session_feet(path: Path) -> dict[str, np.ndarray]:
    """Each foot's (N, 32, 22) counts in a session, decoded as the daemon decodes them."""
    from scotti.firmware_protocol.assembly import FrameAssembler
    from scotti.firmware_protocol.framing import StreamDecoder

    decoder, assembler = StreamDecoder(), FrameAssembler()
    frames: dict[str, list[np.ndarray]] = {"left": [], "right": []}
    for record in read_session(path).packets:
        for item in decoder.feed(record.data):
            for frame in assembler.push(item, record.t_ns):  # type: ignore[arg-type]
                frames[("left", "right")[int(frame.foot)]].append(frame.counts)
    return {f: np.stack(v) for f, v in frames.items() if v}


def import_ok(source: Path, out: Path, *extra: str) -> None:
    assert main(["import", str(source), "-o", str(out), *extra]) == 0


def import_fails(source: Path, out: Path, capsys: pytest.CaptureFixture[str], *extra: str) -> str:
    assert main(["import", str(source), "-o", str(out), *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0, err  # one line
    return err


# --- detection ----------------------------------------------------------------


def test_each_format_is_told_by_its_header_not_its_name(tmp_path: Path) -> None:
    t = np.arange(5) / 100
    cells = np.full((5, 99), 50.0)
    files = {
        "pedar": write_pedar(tmp_path / "a.dat", t, {"left": cells, "right": cells}),
        "fscan": write_fscan(tmp_path / "b.dat", np.full((3, 8, 5), 10.0)),
        "xsensor": write_xsensor(
            tmp_path / "c.dat", datetime(2022, 8, 16, 8), 0.013, {"LF": np.ones((3, 6, 4))}
        ),
        "moticon": write_moticon(tmp_path / "d.dat", t, {"left": np.ones((5, 16))}),
        "gaitpdb": write_gaitpdb(tmp_path / "e.dat", t, np.ones((5, 8)), np.ones((5, 8)), gz=True),
    }
    for name, path in files.items():
        assert detect(path) == name
    (tmp_path / "plain.csv").write_text("t,a,b\n0,1,2\n")
    assert detect(tmp_path / "plain.csv") == "table"
    (tmp_path / "notes.txt").write_text("hello\n")
    with pytest.raises(InputError, match=r"notes\.txt: not a format this importer knows"):
        detect(tmp_path / "notes.txt")


# --- reading: what each file says comes back ----------------------------------


def test_pedar_cells_times_and_header(tmp_path: Path) -> None:
    t = 0.01 + np.arange(200) / 100
    left, right = RNG.uniform(0, 300, (200, 99)), RNG.uniform(0, 300, (200, 99))
    rec = read_vendor(write_pedar(tmp_path / "p.asc", t, {"left": left, "right": right}))
    assert rec.format == "pedar"
    assert rec.rate_hz == 100
    assert rec.units == "kPa"
    np.testing.assert_allclose(rec.times_s, t)
    np.testing.assert_allclose(rec.feet["left"].values, left, atol=5e-4)
    np.testing.assert_allclose(rec.feet["right"].values, right, atol=5e-4)
    assert rec.feet["left"].kpa_per_unit == 1.0
    assert rec.feet["left"].layout == "pedar-x-99"
    assert rec.feet["left"].layout_size == "y"  # from the sensor type
    assert rec.info["mask_definition"]["right"] == list(range(1, 100))
    only_right = read_vendor(write_pedar(tmp_path / "r.asc", t, {"right": right}))
    assert list(only_right.feet) == ["right"]


def test_fscan_grid_outline_scale_and_foot(tmp_path: Path) -> None:
    outline = insole_outline(20, 8, "left")
    frames = np.where(outline, RNG.integers(0, 50, (10, 20, 8)) * 6.0, np.nan)
    rec = read_vendor(write_fscan(tmp_path / "w.asf", frames, start_frame=3))
    data = rec.feet["left"]
    assert list(rec.feet) == ["left"]
    assert rec.absent_feet == ["right"]
    np.testing.assert_array_equal(data.mask, outline)
    assert rec.info["outline"][0] == "".join("1" if v else "0" for v in outline[0])
    np.testing.assert_array_equal(data.values, np.nan_to_num(frames))
    np.testing.assert_allclose(rec.times_s, np.arange(10) * 0.032)
    assert rec.rate_hz == pytest.approx(31.25)
    assert data.kpa_per_unit == 1.0
    assert data.orientation is not None
    assert not data.orientation.medial_first_col
    # the mirror image is a right insole, its big toe at the first column seen from above
    right = read_vendor(write_fscan(tmp_path / "r.asf", frames[:, :, ::-1]))
    assert list(right.feet) == ["right"]
    assert right.feet["right"].orientation.medial_first_col
    assert foot_from_outline(outline)[0] == "left"
    # a symmetric outline says nothing: the name's last letter, else the caller
    square = np.full((2, 4, 3), 6.0)
    with pytest.raises(InputError, match=r"trial\.asf: which foot\? .* --foot left or right"):
        read_vendor(write_fscan(tmp_path / "trial.asf", square))
    assert list(read_vendor(tmp_path / "trial.asf", foot="right").feet) == ["right"]
    assert list(read_vendor(write_fscan(tmp_path / "FrasP01R.asf", square)).feet) == ["right"]


def test_fscan_raw_units_take_the_calibration_point(tmp_path: Path) -> None:
    rec = read_vendor(write_fscan(tmp_path / "rawL.asf", np.full((2, 4, 3), 5.0), units="Raw"))
    # 75.0001 kg gave a raw sum of 4798 on sensels of 25.8064 mm^2
    expected = 75.0001 * 9.81 / 4798 / 25.8064e-6 / 1000
    assert rec.feet["left"].kpa_per_unit == pytest.approx(expected)
    assert rec.info["calibration"]["from"] == "CALIBRATION_POINT_1"


def test_xsensor_both_feet_time_stamps_and_load(tmp_path: Path) -> None:
    grids = {"LF": RNG.uniform(0, 900, (6, 31, 11)), "RF": RNG.uniform(0, 900, (6, 31, 11))}
    start = datetime(2022, 8, 16, 23, 59, 59, 990000)  # across midnight
    rec = read_vendor(write_xsensor(tmp_path / "x.csv", start, 0.013, grids))
    assert sorted(rec.feet) == ["left", "right"]
    assert rec.units == "mmHg"
    np.testing.assert_allclose(rec.times_s, np.arange(6) * 0.013, atol=1e-9)
    np.testing.assert_allclose(rec.feet["right"].values, grids["RF"], atol=5e-3)
    assert rec.feet["left"].kpa_per_unit == pytest.approx(0.133322)
    assert rec.feet["left"].sensel_area_mm2 == pytest.approx(73.96)
    assert rec.info["frame_numbers"] == [1000, 1005]
    one = read_vendor(write_xsensor(tmp_path / "l.csv", start, 0.013, {"LF": grids["LF"]}))
    assert list(one.feet) == ["left"]


def test_moticon_fills_a_foot_s_holes_cuts_its_late_start_and_keeps_events(tmp_path: Path) -> None:
    t = np.arange(100) / 100
    left = np.repeat(np.arange(100.0)[:, None], 16, axis=1) / 10  # a ramp: holes fill exactly
    right = np.full((100, 16), 2.5)
    rec = read_vendor(
        write_moticon(
            tmp_path / "m.txt",
            t,
            {"left": left, "right": right},
            missing={"left": [0, 1, 2, 40, 41], "right": [60]},
            steps={10: 11, 30: 21, 50: 15},
            events={20: ("Left Events", "Event", "1.00")},
        )
    )
    np.testing.assert_allclose(rec.times_s, t[3:])  # both insoles stream from row 3 on
    np.testing.assert_allclose(rec.feet["left"].values, left[3:], atol=1e-5)
    assert rec.info["filled"]["left"] == {"samples": 2, "longest_s": 0.03}
    assert rec.info["cut_s"] == [0.03, 0.0]
    assert rec.feet["left"].kpa_per_unit == 10.0
    assert rec.feet["left"].layout_size == "7"
    assert rec.events == [
        (0.1, "left heel strike"),
        (0.2, "Left Events: Event 1.00"),
        (0.3, "right heel strike"),
        (0.5, "left toe off"),
    ]
    assert rec.info["tags"] == ["normal"]
    assert rec.info["start_unix"] == 1663250316.241


def test_gaitpdb_gzip_or_not_newtons_and_totals(tmp_path: Path) -> None:
    t = np.arange(300) / 100
    left, right = RNG.uniform(0, 200, (300, 8)), RNG.uniform(0, 200, (300, 8))
    for gz in (False, True):
        rec = read_vendor(
            write_gaitpdb(tmp_path / f"GaCo01_01.txt{'.gz' * gz}", t, left, right, gz=gz)
        )
        assert rec.units == "N"
        assert rec.feet["left"].kpa_per_unit is None
        np.testing.assert_allclose(rec.feet["right"].values, right, atol=5e-3)
        np.testing.assert_allclose(rec.feet["left"].total_force_n, left.sum(axis=1), atol=0.05)
    (tmp_path / "demographics.txt").write_text("ID\tWeight\tHeight\nGaCo01\t83\t1.80\n")
    assert read_vendor(tmp_path / "GaCo01_01.txt").info["demographics"]["Weight"] == "83"


# --- the import: units onto our counts -----------------------------------------


def test_grid_units_reach_our_count_scale(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # 128 kPa everywhere, written in each file's own units: our counts are 1635 on our outline
    mask = insole_mask()
    n = 40
    xs = {"LF": np.full((n, 31, 11), 128 / 0.133322), "RF": np.full((n, 31, 11), 128 / 0.133322)}
    files = [
        write_xsensor(tmp_path / "x.csv", datetime(2022, 1, 1), 0.0125, xs),
        write_fscan(tmp_path / "fL.asf", np.full((n, 16, 6), 128.0), period=0.02),
        write_fscan(tmp_path / "psi_l.asf", np.full((n, 16, 6), 128 / 6.894757), units="PSI"),
    ]
    for source in files:
        out = tmp_path / f"{source.stem}.scotti"
        import_ok(source, out)
        for counts in session_feet(out).values():
            assert (counts[:, mask] == OURS_AT_128_KPA).all()
            assert (counts[:, ~mask] == 0).all()
    said = capsys.readouterr().out
    assert "pressure: xsensor, left 31 x 11, right 31 x 11, mmHg (its units)" in said


def test_cells_are_rendered_by_their_layout(tmp_path: Path) -> None:
    t = np.arange(48) / 100 * 4  # 25 Hz
    n_cm2 = np.round(RNG.uniform(5, 25, 16), 2)
    feet = {"left": np.tile(n_cm2, (48, 1)), "right": np.tile(n_cm2[::-1], (48, 1))}
    out = tmp_path / "m.scotti"
    import_ok(write_moticon(tmp_path / "m.txt", t, feet), out)
    got = session_feet(out)
    for foot, values in feet.items():
        lay = layout("moticon-opengo-16", "7").for_foot(foot)  # type: ignore[arg-type]
        expected = np.rint(counts_from_kpa(CellRenderer(lay)(values[:1] * 10.0)))[0]
        # equal but for rounding at a count's edge (the file's 2 decimals, float32 on the way)
        np.testing.assert_allclose(got[foot], np.broadcast_to(expected, got[foot].shape), atol=1)
        assert (got[foot][:, ~insole_mask()] == 0).all()
        assert got[foot].max() > 1000


def test_point_sensors_carry_the_file_s_total_force(tmp_path: Path) -> None:
    t = np.arange(400) / 100
    load = 300 + 200 * np.sin(np.arange(400) / 20)[:, None]  # N a sensor: well above 20 kPa
    left = load * RNG.uniform(0.5, 1.5, 8)
    right = load[::-1] * RNG.uniform(0.5, 1.5, 8)
    out = tmp_path / "g.scotti"
    import_ok(write_gaitpdb(tmp_path / "g.txt", t, left, right), out)
    feet = session_feet(out)
    force = frame_stats(np.concatenate([feet["left"], feet["right"]], axis=2)).force_n
    times = read_session(out).header.imported["segments"][0]  # type: ignore[index]
    frame_t = times[0] + np.arange(len(force)) / 16
    inner = (frame_t > 0.05) & (frame_t < t[-1] - 0.05)
    for k, values in enumerate((left, right)):
        total = np.interp(frame_t, t, values.sum(axis=1))
        np.testing.assert_allclose(force[inner, k], total[inner], rtol=0.03)


def test_a_file_without_a_scale_wants_the_mass_and_then_carries_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    frames = np.full((40, 16, 6), 7.0)
    source = write_fscan(tmp_path / "rawL.asf", frames, units="Raw", calibration=None)
    err = import_fails(source, tmp_path / "a.scotti", capsys)
    assert err.startswith("scotti import: ")
    assert "rawL.asf: the file gives no usable pressure scale" in err
    assert "--mass-kg" in err
    out = tmp_path / "b.scotti"
    import_ok(source, out, "--mass-kg", "70")
    header = read_session(out).header
    assert header.imported["counts"]["method"] == "body_mass"  # type: ignore[index]
    assert header.subject["mass_kg"] == 70.0  # type: ignore[index]
    # one foot carries half the weight on average: 70 kg g / 2 over 96 sensels of 25.8 mm^2
    kpa = header.imported["pressure"]["feet"]["left"]["kpa_per_unit"]  # type: ignore[index]
    assert kpa * 7.0 * 96 * 25.8064e-3 == pytest.approx(70 * 9.81 / 2)


# --- one foot ------------------------------------------------------------------


def one_foot_session(tmp_path: Path) -> Path:
    outline = insole_outline(20, 8, "left")
    steps = np.clip(np.sin(np.arange(125) / 6.0), 0, None)[:, None, None]  # 4 s of stance/swing
    frames = np.where(outline, 40 + 300 * steps * np.ones((1, 20, 8)), np.nan)
    out = tmp_path / "one.scotti"
    import_ok(write_fscan(tmp_path / "walkL.asf", frames), out)
    return out


def test_a_one_foot_file_sends_nothing_for_the_other_and_says_so(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = one_foot_session(tmp_path)
    printed = capsys.readouterr().out
    assert "right foot: absent from the file, no packets for it" in printed
    assert list(session_feet(out)) == ["left"]
    assert read_session(out).header.imported["pressure"]["absent_feet"] == ["right"]  # type: ignore[index]
    assert main(["session", "info", str(out)]) == 0
    info = capsys.readouterr().out
    assert "right foot absent (one-foot recording: no right packets)" in info


def test_eval_and_the_daemon_call_the_absent_foot_silent(
    tmp_path: Path, tiny_model_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from scotti.daemon.frames.pipeline import Pipeline, PipelineState, Prediction
    from scotti.daemon.input.sources import ReplaySource
    from scotti.daemon.service.counters import Counters
    from scotti.evaluation.replay import replay_session
    from scotti.models.runtime import ScottiRuntime

    out = one_foot_session(tmp_path)
    runtime = ScottiRuntime(tiny_model_path)
    replay = replay_session(out, runtime)
    assert replay.silent_pairs == {"left": 0, "right": replay.pairs}
    assert replay.pairs == 64
    assert main(["eval", str(out), "--model", str(tiny_model_path)]) == 0
    said = [line for line in capsys.readouterr().out.splitlines() if "insole silent" in line]
    assert len(said) == 1
    assert "right insole silent on 64 of 64 pairs" in said[0]

    import asyncio

    predictions: list[Prediction] = []
    states: list[PipelineState] = []

    async def run() -> None:
        pipeline = Pipeline(ReplaySource(out, speed="max"), runtime, Counters())
        await asyncio.wait_for(pipeline.run(predictions.append, states.append, asyncio.Event()), 30)

    asyncio.run(run())
    assert predictions
    assert all("right_filled" in p.flags for p in predictions)
    assert all("out_of_range" in p.flags for p in predictions)
    assert any("right insole silent" in s.reasons for s in states)


# --- mistakes: one line naming the file and the place, exit 2 --------------------


def test_malformed_files_fail_on_one_line_with_their_place(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    t = np.arange(20) / 100
    cells = np.full((20, 99), 50.0)
    pedar = write_pedar(tmp_path / "p.asc", t, {"left": cells, "right": cells})
    lines = pedar.read_text().splitlines()
    cases: list[tuple[str, str, str]] = []  # name, content, expected message

    def case(name: str, text: str, expected: str) -> None:
        cases.append((name, text, expected))

    short = [*lines[:13], "\t".join(lines[13].split("\t")[:150]), *lines[14:]]
    case("short.asc", "\n".join(short), r"short\.asc line 14: 150 values, expected 199")
    bad = [*lines[:12], lines[12].replace("50.000", "5O.000", 1), *lines[13:]]
    case("bad.asc", "\n".join(bad), r"bad\.asc line 13, column 2: '5O\.000' is not a number")
    neg = [*lines[:12], lines[12].replace(" 50.000", "-50.000", 1), *lines[13:]]
    case("neg.asc", "\n".join(neg), r"neg\.asc line 13, column 2: negative value -50")
    fscan = write_fscan(tmp_path / "f.asf", np.full((3, 4, 3), 6.0)).read_text().splitlines()
    cut = [x for i, x in enumerate(fscan) if i != fscan.index("Frame 2") + 2]
    case("rows.asf", "\n".join(cut), r"rows\.asf line \d+: frame 2 has 3 rows, not 4")
    cell = "\n".join(fscan).replace("6,6,6", "6,X,6", 1)
    case("cell.asf", cell, r"cell\.asf line \d+, column 2: 'X' is neither a number nor B")
    big = write_fscan(tmp_path / "b.asf", np.full((2, 4, 3), 6.0), declared_frames=10**6)
    case("declared.asf", big.read_text(), r"declared\.asf: declares 1000000 frames of 4 x 3")
    xs = write_xsensor(
        tmp_path / "x.csv",
        datetime(2022, 1, 1),
        0.013,
        {"LF": np.ones((2, 3, 2)), "RF": np.ones((2, 3, 2))},
    )
    x_lines = xs.read_text(encoding="utf-8").splitlines()
    last_rf = max(i for i, x in enumerate(x_lines) if x.startswith("SENSOR") and "RF" in x)
    case(
        "norf.csv",
        "\n".join(x_lines[:last_rf]),
        r"norf\.csv line \d+: frame 1001 has no complete right",
    )
    mot = write_moticon(
        tmp_path / "m.txt", t, {"left": np.ones((20, 16)), "right": np.ones((20, 16))}
    )
    m_lines = mot.read_text(encoding="utf-8").splitlines()
    row = m_lines[12].split("\t")
    row[3] = ""
    case(
        "hole.txt",
        "\n".join([*m_lines[:12], "\t".join(row), *m_lines[13:]]),
        r"hole\.txt line 13, column 4: left pressure cell empty",
    )
    g = (
        write_gaitpdb(tmp_path / "g.txt", t, np.ones((20, 8)), np.ones((20, 8)))
        .read_text()
        .splitlines()
    )
    total = [*g[:4], g[4].rsplit("\t", 1)[0] + "\t99.00", *g[5:]]
    case("total.txt", "\n".join(total), r"total\.txt line 5, column 19: right total 99 N is not")
    back = [*g[:6], g[6].replace("0.0600", "0.0400", 1), *g[7:]]
    case("back.txt", "\n".join(back), r"back\.txt line 7, column 1: time stamp earlier than")
    same = [*m_lines[:11], m_lines[11].replace("0.01", "0.00", 1), *m_lines[12:]]
    case("same.txt", "\n".join(same), r"same\.txt line 12, column 1: time stamp duplicate")
    for name, text, expected in cases:
        path = tmp_path / name
        path.write_text(text + "\n", encoding="utf-8")
        err = import_fails(path, tmp_path / "out.scotti", capsys)
        assert err.startswith("scotti import: ")
        assert re.search(expected, err), (name, err)


def test_oversized_and_inflating_inputs_are_refused_without_reading_them(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    long_line = tmp_path / "long.txt"
    long_line.write_text(
        "# Start time: x\n# Sensor insoles: L, R\n# time\t" + "x" * (2 << 20) + "\n"
    )
    err = import_fails(long_line, tmp_path / "o.scotti", capsys)
    assert "long.txt line 3: line longer than 1048576 bytes" in err
    bomb = tmp_path / "GaCo09_01.txt.gz"
    bomb.write_bytes(gzip.compress((b" " * 999 + b"\n") * 20_000))  # 20 MB of blanks in 56 kB
    err = import_fails(bomb, tmp_path / "o.scotti", capsys, "--format", "gaitpdb")
    assert "GaCo09_01.txt.gz: inflates past 64 x its size: not a recording" in err


def test_vendor_files_refuse_table_keys_and_a_wrong_format(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    t = np.arange(20) / 100
    source = write_gaitpdb(tmp_path / "g.txt", t, np.ones((20, 8)), np.ones((20, 8)))
    err = import_fails(source, tmp_path / "o.scotti", capsys, "--grid", "4x2")
    assert "pressure.cols, pressure.rows: for tables only; a gaitpdb file says its own" in err
    err = import_fails(source, tmp_path / "o.scotti", capsys, "--counts-per-kpa", "2")
    assert "[counts] is for tables" in err
    err = import_fails(source, tmp_path / "o.scotti", capsys, "--format", "pedar")
    assert "g.txt" in err
    assert "not a pedar export" in err
    import_ok(source, tmp_path / "o.scotti", "--format", "gaitpdb")


def test_the_fuzzer_s_vendor_findings_stay_fixed(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A stray carriage return in an XSENSOR line (csv.Error); values past float32's range
    (overflow warnings when cast); an infinite Moticon step code (OverflowError); a 3 kB
    insole size echoed whole: each one line naming its place."""
    t = np.arange(20) / 100
    huge = "1.7976931348623157e308"
    xs = write_xsensor(tmp_path / "x.csv", datetime(2022, 1, 1), 0.013, {"LF": np.ones((2, 3, 2))})
    x_lines = xs.read_text(encoding="utf-8").splitlines()
    sensels = x_lines.index("SENSELS" + "," * 19)
    load = next(i for i, x in enumerate(x_lines) if x.startswith("Est. Load"))
    mot = write_moticon(tmp_path / "m.txt", t, {"left": np.ones((20, 16))}, steps={3: 11})
    m_lines = mot.read_text(encoding="utf-8").splitlines()
    row = m_lines[11].split("\t")
    cases: dict[str, tuple[list[str], str]] = {
        "cr.csv": (
            [*x_lines[: sensels + 2], "1,\r1", *x_lines[sensels + 3 :]],
            rf"cr\.csv line {sensels + 3}: not a CSV line \(new-line character seen",
        ),
        "big.csv": (
            [*x_lines[: sensels + 2], f"{huge},1", *x_lines[sensels + 3 :]],
            rf"big\.csv line {sensels + 3}, column 1: value 1\.79769e\+308 is past any sensor",
        ),
        "load.csv": (
            [*x_lines[:load], f"Est. Load (N),{huge}", *x_lines[load + 1 :]],
            rf"load\.csv line {load + 1}, column 2: value 1\.79769e\+308 is past",
        ),
        "big.txt": (
            [*m_lines[:11], "\t".join([*row[:5], huge, *row[6:]]), *m_lines[12:]],
            r"big\.txt line 12, column 6: value 1\.79769e\+308 is past any sensor",
        ),
        "force.txt": (
            [*m_lines[:11], "\t".join([*row[:20], huge, *row[21:]]), *m_lines[12:]],
            r"force\.txt line 12, column 21: value 1\.79769e\+308 is past any sensor",
        ),
        "step.txt": (
            [*m_lines[:13], m_lines[13].replace("11.00", "inf"), *m_lines[14:]],
            r"step\.txt line 14, column \d+: step code inf is not a code",
        ),
        "size.txt": (
            [m.replace("# Size: 7", "# Size: " + "7" * 3000) for m in m_lines],
            r"size\.txt: layout moticon-opengo-16 has no size '7{50,}\.\.\.' \(known",
        ),
    }
    g = write_gaitpdb(tmp_path / "g.txt", t, np.ones((20, 8)), np.ones((20, 8))).read_text()
    g_lines = g.splitlines()
    cases["GaCo01_01.txt"] = (
        [*g_lines[:4], g_lines[4].replace("1.00", huge, 1), *g_lines[5:]],
        r"GaCo01_01\.txt line 5, column 2: value 1\.79769e\+308 is past any sensor",
    )
    pedar = write_pedar(tmp_path / "p.asc", t, {"left": np.full((20, 99), 5.0)})
    p_lines = pedar.read_text().splitlines()
    cases["big.asc"] = (
        [*p_lines[:12], p_lines[12].replace("  5.000", huge, 1), *p_lines[13:]],
        r"big\.asc line 13, column 2: value 1\.79769e\+308 is past any sensor",
    )
    fscan = write_fscan(tmp_path / "f.asf", np.full((3, 4, 3), 6.0)).read_text().splitlines()
    first_row = fscan.index("Frame 1") + 1
    cases["big.asf"] = (
        [*fscan[:first_row], f"6,{huge},6", *fscan[first_row + 1 :]],
        rf"big\.asf line {first_row + 1}, column 2: value 1\.79769e\+308 is past any sensor",
    )
    for name, (text, expected) in cases.items():
        path = tmp_path / name
        path.write_text("\n".join(text) + "\n", encoding="utf-8", newline="")
        err = import_fails(path, tmp_path / "out.scotti", capsys)
        assert re.search(expected, err), (name, err)
        assert len(err) < 300, err
