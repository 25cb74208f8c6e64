"""The bench's model step alone (``--step-batches``) and its model floor on either form
the daemon serves: the paper form's step on frames and cached embeddings, the
streaming-native form's on frames and warm key/value caches, as its runtime takes them."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("torch")
from scotti.daemon.tools.bench import main as bench_main
from scotti.daemon.tools.bench_model import model_cpu_ms
from scotti.daemon.tools.bench_table import COLUMNS, HEADER
from scotti.daemon.tools.step_costs import run_step, step_costs, step_inputs, warm_kv_caches
from scotti.models.contract import MAX_COUNT
from scotti.models.errors import ModelInputError
from scotti.models.kv_streaming import KvStepRuntime, KvStreamingWindow, open_step_model
from scotti.models.runtime import ScottiRuntime

pytestmark = pytest.mark.torch

SIZES = [1, 3]


def _table(out: str) -> dict[int, tuple[float, float]]:
    """``| b | min | median |`` rows of the step table, by batch size."""
    rows = {}
    for line in out.splitlines():
        cells = [c.strip() for c in line.strip("|").split("|")]
        if len(cells) == 3 and cells[0].isdigit():
            rows[int(cells[0])] = (float(cells[1]), float(cells[2]))
    return rows


def test_the_kv_inputs_are_a_warm_window_s_cache_and_the_kv_runtime_takes_them(
    kv_model: Path,
) -> None:
    runtime = open_step_model(kv_model)
    assert isinstance(runtime, KvStepRuntime)
    inputs = step_inputs(runtime, SIZES)
    for b, (frames, past, valid) in inputs.items():
        assert frames.shape == (b, *runtime.frame_shape)
        assert past.shape == (b, runtime.window - 1, runtime.slots, runtime.embed_dim)
        assert valid.shape == (b, runtime.window - 1)
        assert np.all(valid == 1.0)  # warm: every slot holds a frame
        batch = run_step(runtime, frames, (past, valid))  # the runtime checks the shapes
        assert batch.pose.shape[0] == b
        assert np.all(np.isfinite(batch.pose))
    # A cache one slot short is refused: the shapes above are what the runtime checks.
    frames, past, valid = inputs[1]
    with pytest.raises(ModelInputError, match="past must be"):
        run_step(runtime, frames, (past[:, 1:], valid[:, 1:]))


def test_the_warm_caches_are_the_rows_a_streaming_window_holds(kv_model: Path) -> None:
    runtime = open_step_model(kv_model)
    assert isinstance(runtime, KvStepRuntime)
    past, valid = warm_kv_caches(runtime, 2)
    rng = np.random.default_rng(1)  # warm_kv_caches' draws: T-1 frames for both windows
    draws = [
        rng.integers(0, MAX_COUNT // 3, (2, *runtime.frame_shape)).astype(np.float32)
        for _ in range(runtime.window - 1)
    ]
    window = KvStreamingWindow(runtime)
    for frames in draws:
        assert window.push(frames[1]) is None  # still warming: T-1 frames fill the cache
    np.testing.assert_array_equal(window.past(), past[1])
    np.testing.assert_array_equal(window.valid(), valid[1])
    frame = np.full(runtime.frame_shape, 50.0, dtype=np.float32)
    pushed = window.push(frame)
    assert pushed is not None  # the next frame predicts: the cache was warm
    stepped = run_step(runtime, frame[None], (past[1:], valid[1:])).row(0)
    np.testing.assert_allclose(stepped.pose, pushed.pose, atol=1e-6)


def test_the_paper_form_s_inputs_are_the_draws_its_figures_were_made_with(
    tiny_model_path: Path,
) -> None:
    runtime = open_step_model(tiny_model_path)
    assert isinstance(runtime, ScottiRuntime)
    inputs = step_inputs(runtime, SIZES)
    rng = np.random.default_rng(0)  # frames then embeddings, size by size
    for b in SIZES:
        frames = rng.integers(0, MAX_COUNT // 3, (b, *runtime.frame_shape)).astype(np.float32)
        past = rng.normal(size=(b, runtime.window - 1, runtime.embed_dim)).astype(np.float32)
        assert len(inputs[b]) == 2
        np.testing.assert_array_equal(inputs[b][0], frames)
        np.testing.assert_array_equal(inputs[b][1], past)


@pytest.mark.parametrize("form", ["paper", "kv"])
def test_step_costs_prints_finite_figures_for_either_form(
    form: str, kv_model: Path, tiny_model_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    model = kv_model if form == "kv" else tiny_model_path
    assert step_costs(model, SIZES, repeats=3) == 0
    out = capsys.readouterr().out
    assert ("streaming-native" in out) == (form == "kv"), out
    table = _table(out)
    assert sorted(table) == SIZES, out
    for low, median in table.values():
        assert math.isfinite(median)
        assert 0 <= low <= median


def test_the_bench_option_times_a_streaming_native_export(
    kv_model: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert bench_main(["--step-batches", "1", "2", "--model", str(kv_model)]) == 0
    out = capsys.readouterr().out
    assert f"model step {kv_model.name}, streaming-native" in out
    assert sorted(_table(out)) == [1, 2]


@pytest.mark.parametrize("form", ["paper", "kv"])
def test_the_floor_runs_on_either_form(form: str, kv_model: Path, tiny_model_path: Path) -> None:
    model = kv_model if form == "kv" else tiny_model_path
    floor = model_cpu_ms(model, [3, 1, 3], seconds=0.1)
    assert sorted(floor) == SIZES
    assert all(math.isfinite(v) and v > 0 for v in floor.values()), floor


@pytest.mark.mosquitto
def test_the_bench_runs_the_daemon_and_its_floor_on_a_streaming_native_export(
    kv_model: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = ["--pairs", "2", "--seconds", "1.5", "--warmup", "0.5", "--modes", "batch"]
    code = bench_main([*args, "--model", str(kv_model)])
    out = capsys.readouterr().out
    assert code == 0, out  # the daemon published for both pairs
    assert f"model {kv_model.name}," in out
    floor = _cells(out, "| 2 | ", 3)  # the floor at the engine's batch, min(pairs, max_batch)
    assert len(floor) == 1, out
    ms, share = float(floor[0][1]), floor[0][2]
    assert math.isfinite(ms)
    assert ms > 0
    (row,) = _cells(out, "| 2 | batched", COLUMNS)
    column = dict(zip([c.strip() for c in HEADER.strip("|").split("|")], row, strict=True))
    assert column["model per pair"] == share  # the row's floor is the kv model's
    assert math.isfinite(float(column["daemon / model"].rstrip("x")))


def _cells(out: str, start: str, count: int) -> list[list[str]]:
    """The cells of the table lines that start with ``start`` and have ``count`` cells."""
    lines = [line for line in out.splitlines() if line.startswith(start)]
    rows = [[c.strip() for c in line.strip("|").split("|")] for line in lines]
    return [r for r in rows if len(r) == count]
