"""Device, precision and batches built ahead: what runs on a CPU-only machine."""

from __future__ import annotations

import json
import re
import threading
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("torch")
import torch
from scotti.cli.main import main
from scotti.export.data import load_session
from scotti.export.devices import DeviceError, autocast, resolve_device
from scotti.export.model import Scotti, ScottiConfig
from scotti.export.prefetch import prefetched
from scotti.export.subnormals import flushing_denormals
from scotti.export.train import Trainer, TrainOptions
from scotti.export.windows import WindowDataset

from tests.support.export_sessions import TINY_MODEL, write_session

pytestmark = pytest.mark.torch

TINY: dict[str, Any] = {**TINY_MODEL, "dropout": 0.2}


@pytest.fixture(scope="module")
def data(tmp_path_factory: pytest.TempPathFactory) -> WindowDataset:
    path = write_session(tmp_path_factory.mktemp("dev") / "a.scotti", 90, subject="a")
    return WindowDataset([load_session(path)], window=TINY["window"])


def run(data: WindowDataset, **changes: Any) -> Trainer:
    torch.manual_seed(0)
    opts = TrainOptions(epochs=1, batch=8, chunk=4, lr=1e-3, progress_bar=False, **changes)
    trainer = Trainer(Scotti(ScottiConfig.from_dict(TINY)), data, None, opts)
    trainer.fit()
    return trainer


def test_batches_built_ahead_change_no_number(data: WindowDataset) -> None:
    inline, ahead = run(data, workers=0), run(data, workers=3)
    assert len(inline.step_losses) > 3
    assert inline.step_losses == ahead.step_losses
    for name, value in inline.model.state_dict().items():
        assert torch.equal(value, ahead.model.state_dict()[name]), name


def test_prefetch_keeps_order_and_stops_cleanly() -> None:
    threads = {threading.current_thread().name}

    def build(i: int) -> int:
        threads.add(threading.current_thread().name)
        return i * i

    assert list(prefetched(range(20), build, workers=2)) == [i * i for i in range(20)]
    assert any(name.startswith("scotti-batches") for name in threads)
    early = prefetched(range(1000), build, workers=2)
    assert next(early) == 0
    early.close()  # time is up: the pool goes, queued work is dropped
    assert not any(t.name.startswith("scotti-batches") for t in threading.enumerate())


def test_bf16_trains_on_the_cpu_close_to_fp32(data: WindowDataset) -> None:
    fp32, bf16 = run(data), run(data, precision="bf16")
    assert all(torch.isfinite(torch.tensor(bf16.step_losses)))
    assert bf16.step_losses != fp32.step_losses  # it did run in bfloat16
    first = fp32.step_losses[0]
    assert abs(bf16.step_losses[0] - first) < 0.05 * first
    with autocast(torch.device("cpu"), "bf16"):
        y = torch.nn.functional.linear(torch.ones(2, 4), torch.ones(3, 4))
    assert y.dtype == torch.bfloat16


def test_device_choice(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    assert resolve_device("cpu") == torch.device("cpu")
    expected = "cuda" if torch.cuda.is_available() else "cpu"
    assert resolve_device("auto").type == expected
    if torch.cuda.is_available():
        pytest.skip("this machine has a GPU: the no-GPU error cannot show")
    with pytest.raises(DeviceError, match="no CUDA device"):
        resolve_device("cuda")
    write_session(tmp_path / "a.scotti", 30, subject="a")
    args = [str(tmp_path / "a.scotti"), "-o", str(tmp_path / "r"), "--device", "cuda"]
    assert main(["train", *args]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("scotti train: --device cuda")
    assert "\n" not in err


SUBNORMAL = 1e-39  # below float32's smallest normal, 1.18e-38


def _subnormal_survives() -> bool:
    return bool((torch.full((8,), SUBNORMAL) * 1.0).ne(0).all())


def test_flushing_denormals_covers_threads_started_inside_and_ends_with_it() -> None:
    assert _subnormal_survives()  # the default: subnormals are kept (and slow)
    with flushing_denormals() as took:
        assert took
        assert not _subnormal_survives()
        seen: list[bool] = []
        worker = threading.Thread(target=lambda: seen.append(_subnormal_survives()))
        worker.start()
        worker.join()
        assert seen == [False]  # a batch-building thread, say
    assert _subnormal_survives()


def test_training_leaves_the_float_mode_as_it_found_it(tmp_path: Path) -> None:
    write_session(tmp_path / "a.scotti", 90, subject="a")
    args = [str(tmp_path / "a.scotti"), "-o", str(tmp_path / "r"), "--config", json.dumps(TINY)]
    args += ["--batch", "8", "--chunk", "4", "--benchmark", "1", "--device", "cpu"]
    assert main(["train", *args]) == 0
    assert _subnormal_survives()  # a test (or a notebook) that trains keeps IEEE floats


@pytest.mark.slow
def test_benchmark_prints_fp32_and_bf16_side_by_side(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    write_session(tmp_path / "a.scotti", 90, subject="a")
    args = [str(tmp_path / "a.scotti"), "-o", str(tmp_path / "r"), "--config", json.dumps(TINY)]
    args += ["--batch", "8", "--chunk", "4", "--benchmark", "2", "--device", "cpu"]
    assert main(["train", *args]) == 0
    out = capsys.readouterr().out
    assert re.search(r"naive [0-9.]+ windows/s, chunked [0-9.]+ windows/s", out), out
    rates = re.search(r"fp32 ([0-9.]+) windows/s, bf16 ([0-9.]+) windows/s", out)
    assert rates is not None, out
    assert float(rates.group(1)) > 0
    assert float(rates.group(2)) > 0
    assert not (tmp_path / "r" / "last.pt").exists()  # measured, not trained


def test_help_lists_the_device_and_distributed_options(
    capsys: pytest.CaptureFixture[str],
) -> None:
    with pytest.raises(SystemExit) as exited:
        main(["train", "--help"])
    assert exited.value.code == 0
    text = capsys.readouterr().out
    for option in ("--device", "--precision", "--workers", "torchrun", "--val-subjects"):
        assert option in text, option
    assert "--patience" in text
