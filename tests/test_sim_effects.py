"""Each effect, named alone, changes only what it is about; unnamed, it costs nothing."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scotti.firmware_protocol.packets import FrameRows
from scotti.firmware_protocol.session import read_session
from scotti.sim.effects.base import EFFECT_CALLS
from scotti.sim.effects.registry import (
    EFFECT_MODELS,
    EffectError,
    describe_effects,
    parse_effects,
    realistic_effects,
)
from scotti.sim.effects.transport import _gilbert_elliott_bad
from scotti.sim.foot_mask import insole_mask
from scotti.sim.writer import render_counts, write_session

from tests.support.sim_session import Decoded, decode_session
from tests.support.sim_synthetic import synthetic_input, walking

FRAMES = 64
SEED = 11


def _write(path: Path, effects: Sequence[Mapping[str, Any]]) -> Decoded:
    sim = synthetic_input(walking(FRAMES))
    write_session(path, sim, seed=SEED, effects=parse_effects(effects))
    return decode_session(path)


@pytest.fixture(scope="module")
def clean(tmp_path_factory: pytest.TempPathFactory) -> Decoded:
    return _write(tmp_path_factory.mktemp("fx") / "clean.ses", [])


def _frame_records(d: Decoded) -> list[tuple[int, bytes]]:
    """(t_ns, bytes) of every record that holds a FRAME_ROWS packet (type byte 0x01)."""
    from scotti.firmware_protocol.cobs import decode

    out = []
    for r in d.session.packets:
        if decode(r.data[:-1])[1] == 0x01:
            out.append((r.t_ns, r.data))
    return out


def test_unnamed_effects_cost_nothing(tmp_path: Path) -> None:
    before = EFFECT_CALLS.copy()
    _write(tmp_path / "clean.ses", [])
    assert before == EFFECT_CALLS
    _write(tmp_path / "noise.ses", [{"name": "noise"}])
    changed = {k for k in EFFECT_CALLS if EFFECT_CALLS[k] != before.get(k, 0)}
    assert changed == {"noise"}


def test_packet_loss_only_removes_packets(clean: Decoded, tmp_path: Path) -> None:
    lossy = _write(
        tmp_path / "loss.ses",
        [{"name": "packet_loss", "p_good_to_bad": 0.05, "p_bad_to_good": 0.3, "loss_bad": 1.0}],
    )
    kept, all_clean = _frame_records(lossy), _frame_records(clean)
    assert 0 < len(kept) < len(all_clean)
    assert set(kept) <= set(all_clean)
    assert kept == [r for r in all_clean if r in set(kept)]  # same order
    lost = len(all_clean) - len(kept)
    last = lossy.statuses[-1][1]
    assert last.left.packets_lost + last.right.packets_lost <= lost
    assert lossy.counters.errors == 0


def test_loss_per_frame_drops_whole_frames(tmp_path: Path) -> None:
    d = _write(
        tmp_path / "lf.ses", [{"name": "packet_loss", "unit": "frame", "p_good_to_bad": 0.1}]
    )
    blocks: dict[tuple[int, int], int] = {}
    for _, b in d.blocks:
        blocks[(int(b.foot), b.seq)] = blocks.get((int(b.foot), b.seq), 0) + 1
    assert set(blocks.values()) == {4}
    assert len(blocks) < 2 * FRAMES


def test_gilbert_elliott_bursts_have_the_stated_mean_lengths() -> None:
    rng = np.random.default_rng(0)
    bad = _gilbert_elliott_bad(200_000, 0.01, 0.25, rng)
    starts = np.flatnonzero(np.diff(bad.astype(int)) == 1)
    assert abs(bad.mean() - 0.01 / (0.01 + 0.25)) < 0.01
    assert abs(bad.sum() / len(starts) - 4.0) < 0.5  # mean burst 1 / p_bad_to_good


def test_dead_row_touches_only_that_row(clean: Decoded, tmp_path: Path) -> None:
    d = _write(tmp_path / "dead.ses", [{"name": "dead_line", "foot": "right", "index": 26}])
    a, b = clean.frame_counts(FRAMES), d.frame_counts(FRAMES)
    assert not (b[:, 1, 26] > 0).any()
    assert (a[:, 1, 26] > 0).any()
    a[:, 1, 26] = b[:, 1, 26]
    np.testing.assert_array_equal(a, b)


def test_shorted_column_reads_full_scale_on_its_taxels(clean: Decoded, tmp_path: Path) -> None:
    effect = {"name": "dead_line", "foot": "left", "axis": "column", "index": 5, "kind": "shorted"}
    d = _write(tmp_path / "short.ses", [effect])
    col = d.frame_counts(FRAMES)[:, 0, :, 5]
    mask = insole_mask()[:, 5]
    assert (col[:, mask] == 4095).all()
    assert (col[:, ~mask] == 0).all()


def test_jitter_only_moves_host_times(clean: Decoded, tmp_path: Path) -> None:
    d = _write(tmp_path / "jitter.ses", [{"name": "jitter", "std_ms": 5.0}])
    a, b = clean.session.packets, d.session.packets
    assert [r.data for r in a] == [r.data for r in b]
    ta, tb = np.array([r.t_ns for r in a]), np.array([r.t_ns for r in b])
    assert (tb >= ta).all()
    assert (tb > ta).any()
    assert (np.diff(tb) >= 0).all()  # in order, as one USB pipe delivers


def test_offset_only_shifts_one_foots_times(clean: Decoded, tmp_path: Path) -> None:
    d = _write(tmp_path / "offset.ses", [{"name": "foot_offset", "foot": "right", "offset_ms": 40}])
    for foot, shift in ((0, 0), (1, 40_000_000)):
        a = [(t, b) for t, b in clean.blocks if b.foot == foot]
        b = [(t, b) for t, b in d.blocks if b.foot == foot]
        assert [x[1] for x in a] == [x[1] for x in b]
        assert all(tb - ta == shift for (ta, _), (tb, _) in zip(a, b, strict=True))
    times = [r.t_ns for r in d.session.packets]
    assert times == sorted(times)


def test_drift_only_changes_board_clocks(clean: Decoded, tmp_path: Path) -> None:
    d = _write(tmp_path / "drift.ses", [{"name": "clock_drift", "left_ppm": 0, "right_ppm": 500}])
    assert [t for t, _ in clean.blocks] == [t for t, _ in d.blocks]
    for (_, a), (_, b) in zip(clean.blocks, d.blocks, strict=True):
        np.testing.assert_array_equal(a.samples, b.samples)
        assert (a.foot, a.seq, a.row_start) == (b.foot, b.seq, b.row_start)
        if a.foot == 0:
            assert a.board_clock_us == b.board_clock_us
    last_a, last_b = clean.blocks[-1][1], d.blocks[-1][1]
    elapsed = FRAMES - 1
    expected = round(elapsed * 62_500 * 500e-6)
    assert abs((last_b.board_clock_us - last_a.board_clock_us) - expected) <= 1


def test_corruption_only_alters_bytes_on_the_line(clean: Decoded, tmp_path: Path) -> None:
    effect = {"name": "line_corruption", "flip_rate_per_byte": 2e-4, "garbage_per_s": 2.0}
    d = _write(tmp_path / "corrupt.ses", [effect])
    assert d.counters.errors > 0
    good = [b for _, b in clean.blocks]
    survivors = [b for _, b in d.blocks]
    assert 0 < len(survivors) < len(good)
    assert all(any(s == g for g in good) for s in survivors)
    assert d.counters.bytes_in > clean.counters.bytes_in  # garbage was inserted


def test_unplug_removes_exactly_the_span(clean: Decoded, tmp_path: Path) -> None:
    d = _write(tmp_path / "unplug.ses", [{"name": "unplug", "start_s": 1.0, "duration_s": 1.5}])
    t0 = clean.session.labels[0].t_ns
    start, end = t0 + 1_000_000_000, t0 + 2_500_000_000
    times = [r.t_ns for r in d.session.packets]
    assert not any(start <= t < end for t in times)
    outside = [(t, b) for t, b in clean.blocks if not start <= t < end]
    assert [b for _, b in outside] == [b for _, b in d.blocks]
    assert [t for t, _ in outside] == [t for t, _ in d.blocks]
    # the receiver rebooted at the replug: its uptime restarted
    after = [s for t, s in d.statuses if t >= end]
    assert after
    assert after[0].uptime_s <= 1


def test_noise_is_seeded_and_stays_on_the_insole(tmp_path: Path) -> None:
    sim = synthetic_input(walking(16))
    noisy = parse_effects([{"name": "noise", "std_counts": 10}])
    a = render_counts(sim, noisy, seed=1)
    np.testing.assert_array_equal(a, render_counts(sim, noisy, seed=1))
    assert not np.array_equal(a, render_counts(sim, noisy, seed=2))
    clean = render_counts(sim, seed=1).astype(float)  # the same insole (gains drawn per seed)
    diff = a.astype(float) - clean
    assert not diff[:, :, ~insole_mask()].any()
    assert 5 < diff[clean > 100].std() < 15


@pytest.mark.parametrize(
    "effect",
    [
        {"name": "crosstalk", "fraction": 0.05},
        {"name": "hysteresis", "fraction": 0.3},
        {"name": "creep", "fraction": 0.2, "tau_s": 1.0},
    ],
)
def test_sensor_effects_change_counts_only(
    clean: Decoded, tmp_path: Path, effect: dict[str, Any]
) -> None:
    d = _write(tmp_path / "s.ses", [effect])
    assert [t for t, _ in clean.blocks] == [t for t, _ in d.blocks]
    heads = [(b.foot, b.seq, b.board_clock_us, b.row_start) for _, b in d.blocks]
    assert heads == [(b.foot, b.seq, b.board_clock_us, b.row_start) for _, b in clean.blocks]
    assert not np.array_equal(clean.frame_counts(FRAMES), d.frame_counts(FRAMES))


def test_hysteresis_reads_high_on_unloading_and_creep_grows_under_load() -> None:
    from scotti.sim.effects.sensor_memory import Creep, CreepParams, Hysteresis, HysteresisParams

    ramp = np.concatenate([np.linspace(0, 100, 8), np.linspace(100, 0, 8)]).astype(np.float32)
    x = np.broadcast_to(ramp[:, None, None, None], (16, 2, 1, 1)).copy()
    y = Hysteresis(HysteresisParams(fraction=0.2, tau_s=1.0), 16.0).apply(x)
    np.testing.assert_allclose(y[:8], x[:8])  # loading: exact
    assert (y[9:15] > x[9:15]).all()  # unloading: lags high
    hold = np.full((64, 2, 1, 1), 100.0, np.float32)
    z = Creep(CreepParams(fraction=0.1, tau_s=1.0), 16.0).apply(hold)
    assert (np.diff(z[:, 0, 0, 0]) > 0).all()
    assert 109 < z[-1, 0, 0, 0] <= 110.0


def test_same_seed_same_bytes_with_effects(tmp_path: Path) -> None:
    effects = realistic_effects(np.random.default_rng(3))
    _write(tmp_path / "a.ses", effects)
    _write(tmp_path / "b.ses", effects)
    assert (tmp_path / "a.ses").read_bytes() == (tmp_path / "b.ses").read_bytes()
    assert not read_session(tmp_path / "a.ses").truncated


@pytest.mark.parametrize(
    ("raw", "message"),
    [
        ({"name": "fog"}, "unknown effect 'fog'"),
        ({"name": "noise", "std_counts": -1}, "std_counts"),
        ({"name": "noise", "sigma": 1}, "sigma"),
        ({"std_counts": 1}, "needs a 'name'"),
        ({"name": "dead_line", "foot": "middle"}, "foot"),
        ({"name": "gain_spread", "sigma": 0.2}, "part of the insole now: set gain_sigma"),
        ({"name": "transfer"}, "part of the insole now"),
    ],
)
def test_bad_effect_tables_are_one_line_errors(raw: dict[str, Any], message: str) -> None:
    with pytest.raises(EffectError, match=message) as info:
        parse_effects([raw])
    assert "\n" not in str(info.value)


def test_every_effect_is_documented_with_defaults() -> None:
    docs = describe_effects()
    assert set(docs) == set(EFFECT_MODELS)
    for name, model in EFFECT_MODELS.items():
        assert len(docs[name]["doc"]) > 40, name
        model()  # typical values are the defaults: every effect can be named bare
    text = (Path(__file__).parents[1] / "sim" / "EFFECTS.md").read_text()
    for name in EFFECT_MODELS:
        assert f"`{name}`" in text, name


def test_frame_rows_survive_realistic_effects(tmp_path: Path) -> None:
    d = _write(tmp_path / "real.ses", realistic_effects(np.random.default_rng(0)))
    assert len(d.blocks) > 0.9 * FRAMES * 8
    assert all(isinstance(b, FrameRows) for _, b in d.blocks)
