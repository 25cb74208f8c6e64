"""Training copies through foreign insoles: our curve both ways, force kept by the grids,
our insole as the identity, rails and zeros, time resampling, and the flag end to end."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scotti.export import sensor_transfer as st
from scotti.importers.timebase import box_average
from scotti.models.contract import FRAME_COLS, FRAME_RATE_HZ, FRAME_ROWS, MAX_COUNT
from scotti.models.insole import DEFAULT_TRANSFER, Transfer, counts_from_kpa, insole_mask

from tests.support.export_sessions import TINY_MODEL

RAIL = DEFAULT_TRANSFER.saturation_counts


def plantar_kpa(frames: int = 24, seed: int = 0) -> np.ndarray:
    """(frames, 32, 44) kPa: a heel and a forefoot blob per foot that move and swell, on
    our outline (0 beyond it), peaks of a few hundred kPa as under a standing person."""
    rng = np.random.default_rng(seed)
    rows, cols = np.mgrid[0:FRAME_ROWS, 0:FRAME_COLS].astype(np.float32)
    out = np.zeros((frames, FRAME_ROWS, 2 * FRAME_COLS), dtype=np.float32)
    for k in range(frames):
        for foot in (0, 1):
            load = 0.5 + 0.5 * np.sin(0.3 * k + foot * np.pi)
            heel = np.exp(-((rows - 26 + k % 3) ** 2 + (cols - 11) ** 2) / 12.0)
            fore = np.exp(-((rows - 7) ** 2 + (cols - 8 - foot) ** 2) / 20.0)
            kpa = 400.0 * load * heel + 250.0 * (1.0 - load) * fore + rng.uniform(0, 5)
            out[k, :, foot * FRAME_COLS : (foot + 1) * FRAME_COLS] = kpa * insole_mask()
    return out


def counts_of(kpa: np.ndarray) -> np.ndarray:
    """Whole counts as the wire carries them."""
    return np.rint(counts_from_kpa(kpa)).astype(np.float32)


# --- our curve ---------------------------------------------------------------------


def test_our_curve_inverts_between_threshold_and_rail() -> None:
    kpa = np.linspace(DEFAULT_TRANSFER.threshold_kpa + 0.5, 2000.0, 5000, dtype=np.float32)
    back = st.kpa_from_counts(counts_from_kpa(kpa))
    np.testing.assert_allclose(back, kpa, rtol=2e-3)
    whole = np.arange(MAX_COUNT + 1, dtype=np.float32)
    np.testing.assert_allclose(
        st.kpa_from_whole_counts(whole), st.kpa_from_counts(whole), rtol=1e-6
    )
    # Nothing pressed reads 0 kPa; the rail reads the pressure that reaches it, and above
    # the rail (counts an insole with a higher rail may send) the same.
    rail_kpa = st.kpa_from_counts(np.array([RAIL]))[0]
    assert st.kpa_from_counts(np.array([0.0]))[0] == 0.0
    assert counts_from_kpa(np.array([rail_kpa]))[0] == pytest.approx(RAIL, abs=0.01)
    assert st.kpa_from_counts(np.array([4095.0]))[0] == rail_kpa


def test_a_foreign_curve_is_read_as_our_importer_reads_it() -> None:
    kpa = np.linspace(0.0, 5000.0, 20000, dtype=np.float32)
    for curve in (
        Transfer(threshold_kpa=45.0, p_half_kpa=450.0, exponent=0.8, saturation_counts=3800.0),
        Transfer(threshold_kpa=5.0, p_half_kpa=120.0, exponent=1.3, saturation_counts=3100.0),
        DEFAULT_TRANSFER,
    ):
        one_power = st.read_as_ours(kpa, curve)
        composed = st.kpa_from_counts(counts_from_kpa(kpa, curve))
        np.testing.assert_allclose(one_power, composed, rtol=1e-4, atol=1e-3)


# --- geometry ---------------------------------------------------------------------


@pytest.mark.parametrize("grid", [(8, 4), (16, 8), (31, 11), (21, 21), (64, 32), (32, 22)])
def test_grid_round_trips_keep_the_force_on_our_outline(grid: tuple[int, int]) -> None:
    kpa = plantar_kpa(6)[:, :, :FRAME_COLS]
    geometry = st.GridGeometry(*grid)
    cells = geometry.down(kpa)
    assert cells.shape == (6, grid[0] * grid[1])
    back = geometry.up(cells)
    assert back.shape == kpa.shape
    assert not back[:, ~insole_mask()].any()  # nothing beyond our outline
    np.testing.assert_allclose(back.sum(axis=(1, 2)), kpa.sum(axis=(1, 2)), rtol=1e-4)
    if grid[0] * grid[1] < 64:  # a coarse grid smears the blobs out: the peak falls
        assert back.max() < 0.9 * kpa.max()


def test_a_uniform_sole_stays_uniform_through_any_grid() -> None:
    kpa = np.where(insole_mask(), 150.0, 0.0).astype(np.float32)[None]
    for grid in ((8, 4), (13, 7), (64, 32)):
        geometry = st.GridGeometry(*grid)
        np.testing.assert_allclose(geometry.up(geometry.down(kpa)), kpa, rtol=1e-5, atol=1e-3)


@pytest.mark.skipif(not st.cell_layouts(), reason="importers.layouts has no layouts yet")
def test_discrete_cells_render_through_the_importers_layouts() -> None:
    counts = counts_of(plantar_kpa(8))
    for name in st.cell_layouts():
        sensor = st.ForeignSensor(layout=name, rows=0, cols=0)
        out = st.render(counts, sensor)
        assert out.shape == counts.shape
        assert out.dtype == np.float32
        assert not out[:, :, :FRAME_COLS][:, ~insole_mask()].any()
        kpa_in = st.kpa_from_counts(counts).sum()
        kpa_out = st.kpa_from_counts(out).sum()
        # The cells' vendor areas move a cell's pressure a little (importers/layouts.py).
        assert 0.6 < kpa_out / kpa_in < 1.4, name
        assert not st.render(np.zeros_like(counts), sensor).any()


# --- the whole way ----------------------------------------------------------------


def test_our_own_insole_is_the_identity() -> None:
    counts = counts_of(plantar_kpa(30))
    counts[3, 10, 5] = RAIL  # a saturated taxel
    assert st.OURS.native
    out = st.render(counts, st.OURS)
    assert out.dtype == np.float32
    assert out.shape == counts.shape
    np.testing.assert_array_equal(out, counts)
    np.testing.assert_array_equal(st.render(counts.astype(np.uint16), st.OURS), counts)
    # Above our rail an import cannot go: those come back at the rail.
    high = counts.copy()
    high[4, 12, 6] = 4095.0
    assert st.render(high, st.OURS)[4, 12, 6] == RAIL


def test_zeros_stay_zero_and_the_rail_stays_saturated() -> None:
    rng = np.random.default_rng(5)
    zeros = np.zeros((20, FRAME_ROWS, 2 * FRAME_COLS), dtype=np.float32)
    for _ in range(10):
        assert not st.render(zeros, st.draw_sensor(rng, st.SensorDraw(layouts=()))).any()
    mask = np.tile(insole_mask(), (1, 2))
    railed = np.where(mask, RAIL, 0.0).astype(np.float32)[None].repeat(20, axis=0)
    for sensor in (
        st.ForeignSensor(rows=8, cols=4),
        st.ForeignSensor(rows=64, cols=32, rate_hz=50.0, phase=0.25),
        st.ForeignSensor(gain=(1.5, 2.0)),
    ):
        out = st.render(railed, sensor)
        np.testing.assert_array_equal(out[:, mask], RAIL, err_msg=sensor.describe())
        assert not out[:, ~mask].any()


def test_a_softer_film_and_a_lower_gain_read_less() -> None:
    counts = counts_of(plantar_kpa(10))
    soft = st.with_curve(st.OURS, threshold_kpa=45.0, p_half_kpa=450.0)
    for sensor in (soft, replace(st.OURS, gain=(0.5, 0.5))):
        out = st.render(counts, sensor)
        assert out.sum() < 0.8 * counts.sum()
        assert (out <= counts).all()  # the same curve's shape, pressed less: never more
    stronger = st.render(counts, replace(st.OURS, gain=(2.0, 2.0)))
    assert (stronger >= counts).all()
    assert stronger.sum() > 1.2 * counts.sum()


def test_cell_spread_is_drawn_per_sensor_and_repeats() -> None:
    counts = counts_of(plantar_kpa(4))
    sensor = st.ForeignSensor(rows=16, cols=8, cell_sigma=0.3, seed=11)
    a, b = st.render(counts, sensor), st.render(counts, sensor)
    np.testing.assert_array_equal(a, b)
    other = st.render(counts, replace(sensor, seed=12))
    assert not np.array_equal(a, other)


# --- time ---------------------------------------------------------------------------


@pytest.mark.parametrize("rate", st.RATES_HZ)
def test_time_resampling_keeps_a_steady_signal_and_matches_the_importer(rate: float) -> None:
    frames = 40
    steady = np.full((frames, 3), 7.0, dtype=np.float32)
    np.testing.assert_allclose(st.resample_in_time(steady, rate, 0.25), steady, rtol=1e-6)
    ramp = np.linspace(0.0, 39.0, frames, dtype=np.float32)[:, None]
    op = st.time_operator(frames, rate, 0.5)
    dense = st.resample_in_time(np.eye(frames, dtype=np.float32), rate, 0.5)
    np.testing.assert_allclose(op.apply(ramp), dense @ ramp, rtol=1e-5, atol=1e-4)
    # Inside the window (away from the held ends) a straight line stays itself.
    inner = slice(4, frames - 4)
    np.testing.assert_allclose(op.apply(ramp)[inner], ramp[inner], atol=1e-3)
    # What the importer does with the sensor's samples, by its own function.
    period = 1.0 / rate
    before = int(np.ceil(0.5 / FRAME_RATE_HZ / period)) + 1  # samples before frame 0
    s = (0.5 + np.arange(-before, frames * rate / FRAME_RATE_HZ + before)) * period
    wave = np.sin(np.arange(frames) / 3.0).astype(np.float32)[:, None]
    sampled = np.interp(s, np.arange(frames) / FRAME_RATE_HZ, wave[:, 0])[:, None]
    expected = box_average(s, sampled, np.arange(frames) / FRAME_RATE_HZ)
    np.testing.assert_allclose(st.resample_in_time(wave, rate, 0.5), expected, atol=1e-5)


def test_a_slow_sensor_blurs_a_step_in_time() -> None:
    counts = np.zeros((40, FRAME_ROWS, 2 * FRAME_COLS), dtype=np.float32)
    counts[20:, 16, 10] = 2000.0
    out = st.render(counts, replace(st.OURS, rate_hz=8.0, phase=0.5))
    column = out[:, 16, 10]
    assert column[:15].max() == 0.0
    assert column[25:].min() == 2000.0
    assert 0.0 < column[19] < 2000.0 or 0.0 < column[20] < 2000.0  # the step smeared


def test_a_chunk_and_a_whole_session_give_the_same_maps() -> None:
    counts = counts_of(plantar_kpa(72, seed=3))
    rng = np.random.default_rng(9)
    for _ in range(4):
        sensor = st.draw_sensor(rng, st.SensorDraw(layouts=()))
        chunk = st.render(counts, sensor)
        whole = st.render(counts, sensor, whole=True)
        assert np.abs(chunk - whole).max() <= 1.0  # float32 vs float64 rounding at .5


# --- draws and the loader -------------------------------------------------------------


def test_draws_cover_the_ranges_and_repeat_by_seed() -> None:
    draw = st.SensorDraw(layouts=("a", "b"))
    sensors = [st.draw_sensor(np.random.default_rng([4, i]), draw) for i in range(400)]
    again = [st.draw_sensor(np.random.default_rng([4, i]), draw) for i in range(400)]
    assert sensors == again
    grids = [s for s in sensors if s.layout is None]
    assert 0.3 < len(grids) / len(sensors) < 0.7
    assert {s.layout for s in sensors} == {None, "a", "b"}
    assert min(s.rows for s in grids) >= st.GRID_ROWS[0]
    assert max(s.rows for s in grids) <= 64
    assert all(st.GRID_COLS[0] <= s.cols <= min(s.rows, st.GRID_COLS[1]) for s in grids)
    assert {s.rate_hz for s in sensors} == set(st.RATES_HZ)
    t = [s.transfer for s in sensors]
    assert st.THRESHOLD_KPA[0] <= min(x.threshold_kpa for x in t)
    assert max(x.threshold_kpa for x in t) <= st.THRESHOLD_KPA[1]
    assert st.HALF_SCALE_KPA[0] <= min(x.p_half_kpa for x in t)
    assert max(x.p_half_kpa for x in t) <= st.HALF_SCALE_KPA[1]
    gains = np.array([s.gain for s in sensors])
    assert gains.min() > 0.5 * 0.6
    assert gains.max() < 2.0 / 0.6
    assert np.median(gains) == pytest.approx(1.0, abs=0.15)


def test_off_draws_nothing_and_on_always_draws() -> None:
    rng = np.random.default_rng(1)
    before = rng.bit_generator.state
    assert st.draw_transfer(rng, 0.0) is None
    assert rng.bit_generator.state == before
    assert all(st.draw_transfer(rng, 1.0) is not None for _ in range(20))
    drawn = [st.draw_transfer(rng, 0.3) is not None for _ in range(2000)]
    assert 0.25 < np.mean(drawn) < 0.35


def test_render_refuses_another_grid() -> None:
    with pytest.raises(ValueError, match="32 x 22"):
        st.render(np.zeros((4, 16, 16), dtype=np.float32), st.OURS)


# --- the loader and scotti train (torch) ----------------------------------------------


@pytest.fixture(scope="module")
def sessions_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from tests.support.export_sessions import write_session

    d = tmp_path_factory.mktemp("transfer_sessions")
    write_session(d / "a.scotti", 110, subject="a")
    write_session(d / "b.scotti", 60, subject="b")
    return d


@pytest.mark.torch
def test_the_loader_renders_planned_chunks_through_their_sensors(sessions_dir: Path) -> None:
    pytest.importorskip("torch")
    from scotti.export.data import load_session
    from scotti.export.epochs import batch_tensors, plan_epoch
    from scotti.export.train import TrainOptions
    from scotti.export.windows import WindowDataset

    ds = WindowDataset([load_session(sessions_dir / "a.scotti")], window=8)
    off = TrainOptions(batch=8, chunk=4, stride=2, max_shift=0)
    on = replace(off, sensor_transfer=1.0)
    plain = plan_epoch(ds, off, 0)
    assert all(p.sensor is None for b in plain for p in b)
    assert plan_epoch(ds, replace(off, sensor_transfer=0.0), 0)[0][0].shifts.tolist() == (
        plain[0][0].shifts.tolist()
    )
    planned = plan_epoch(ds, on, 0)
    assert all(p.sensor is not None for b in planned for p in b)
    assert plan_epoch(ds, on, 0)[0][0].sensor == planned[0][0].sensor  # a pure function
    frames, targets = batch_tensors(ds, planned[0])
    raw, _ = batch_tensors(ds, [replace(p, sensor=None) for p in planned[0]])
    for got, before, p in zip(frames, raw, planned[0], strict=True):
        assert got.dtype == before.dtype
        assert got.shape == before.shape
        assert got.shape == (p.chunk.frame_count, FRAME_ROWS, 2 * FRAME_COLS)
        x = got.numpy()
        assert np.array_equal(x, np.rint(x))
        assert x.min() >= 0
        assert x.max() <= MAX_COUNT
        expected = st.render(before.numpy(), p.sensor) if p.sensor else before.numpy()
        np.testing.assert_array_equal(x, expected)
    assert int(targets.action.shape[0]) == sum(p.chunk.count for p in planned[0])


@pytest.mark.torch
@pytest.mark.slow
def test_scotti_train_takes_the_flag_and_records_it(
    sessions_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    torch = pytest.importorskip("torch")
    from scotti.cli.main import main

    torch.set_num_threads(1)
    run = tmp_path / "run"
    args = [str(sessions_dir), "-o", str(run), "--config", json.dumps(TINY_MODEL), "--epochs", "1"]
    args += ["--batch", "8", "--chunk", "4", "--stride", "2", "--val-subjects", "b"]
    args += ["--test-fraction", "0", "--no-progress", "--device", "cpu"]
    assert main(["train", *args, "--sensor-transfer", "0.5"]) == 0
    ckpt = torch.load(run / "last.pt", weights_only=True)
    assert ckpt["options"]["sensor_transfer"] == 0.5
    assert np.isfinite(ckpt["history"][-1]["train_loss"])
    for bad in ("1.5", "-0.1", "nan"):
        assert main(["train", *args, "-o", str(tmp_path / "r"), f"--sensor-transfer={bad}"]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("scotti train: --sensor-transfer must be a share between 0 and 1")
        assert "\n" not in err


# --- experiments/insole_transfer.py: whole sessions, labels kept ---------------------


def test_a_session_rendered_through_a_sensor_keeps_its_labels(
    sessions_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments"))
    import insole_transfer
    from scotti.export.data import load_session

    monkeypatch.setattr(insole_transfer, "WORK", tmp_path)
    source = sessions_dir / "a.scotti"
    sensor = st.ForeignSensor(rows=16, cols=8, rate_hz=50.0, phase=0.5, gain=(1.2, 0.8))
    path = insole_transfer.rendered(source, sensor, "grid")
    assert insole_transfer.rendered(source, sensor, "grid") == path  # reused
    before, after = load_session(source), load_session(path)
    assert after.subject == before.subject
    np.testing.assert_array_equal(after.action, before.action)
    np.testing.assert_array_equal(after.has_label, before.has_label)
    np.testing.assert_allclose(after.keypoints, before.keypoints, equal_nan=True)
    np.testing.assert_allclose(after.progress, before.progress, equal_nan=True)
    expected = st.render(before.frames, sensor, whole=True)
    np.testing.assert_array_equal(after.frames, expected.astype(np.uint16))
    assert not np.array_equal(after.frames, before.frames)


def test_pooled_figures_count_wrong_unflagged_predictions() -> None:
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments"))
    import insole_transfer
    from scotti.models.contract import ACTIONS, NO_ACTION, STANDING

    squat, walking = ACTIONS.index("squat"), ACTIONS.index("walking")
    result = {
        "predictions": 6,
        "action_true": [squat, squat, walking, STANDING, STANDING, NO_ACTION],
        "action_pred": [squat, walking, walking, squat, STANDING, squat],
        "progress_true": [0.2, 0.4, 0.5, float("nan"), float("nan"), float("nan")],
        "progress_pred": [0.2, 0.4, 0.5, 0.0, 0.0, 0.0],
        "flags": [[], ["unfamiliar"], [], [], [], []],
        "unfamiliar_all": 1,
    }
    figures = insole_transfer.pooled([result])
    assert figures["accuracy"] == pytest.approx(3 / 5)  # the transition is not scored
    assert figures["squat"] == pytest.approx(0.5)
    assert figures["standing"] == pytest.approx(0.5)
    assert figures["walking"] == 1.0
    assert figures["wrong_unflagged"] == pytest.approx(1 / 5)  # the flagged miss is not
    assert figures["unfamiliar"] == pytest.approx(1 / 6)
