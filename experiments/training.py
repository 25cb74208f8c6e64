"""Budgeted, resumable training runs through ``scotti train``.

A run lives in runs/<group>/<name>/ with ``plan.json``: the epochs and
stride chosen from the measured throughput so that the LR schedule ends
inside the run's share of the budget, and the seconds of training it has
had (``trained_s``). Calling ``train`` again resumes it from last.pt until its
planned epochs are done; each call spends at most the time it is given.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from common import (
    COMMANDS,
    RUNS,
    THROUGHPUT,
    WINDOWS,
    ExperimentError,
    Partition,
    read_json,
    run,
    scotti_command,
    shown,
    write_json,
)

CACHE = RUNS / ".session-cache"
EPOCHS = 3  # epochs a budget is cut into: the schedule's warmup and decay both happen
MAX_STRIDE = 40  # T: a larger stride would skip frames entirely
LR = 1e-3  # short budgets want a brisk learning rate (Adam, warmup + cosine)

# Loss weights per variant: the multi-task model and its single-task variants (Table 3).
VARIANTS: dict[str, str | None] = {
    "multi": None,  # scotti train's defaults: pose 0.01, action 1, progress 1
    "pose": "0.01,0,0",
    "action": "0,1,0",
    "progress": "0,0,1",
}


@dataclass(frozen=True)
class RunSpec:
    run_dir: Path
    partition: Partition
    config: str  # preset name or JSON object, as scotti train --config takes it
    variant: str = "multi"
    threads: int = 2
    val_stride: int = 32  # validation is for the log only: keep it cheap
    lr: float = LR

    def train_args(self, *, epochs: int, stride: int, minutes: float, resume: bool) -> list[str]:
        args = [
            str(self.partition.corpus),
            "-o",
            str(self.run_dir),
            "--config",
            self.config,
            "--test-subjects",
            *self.partition.test,
            "--epochs",
            str(epochs),
            "--stride",
            str(stride),
            "--val-stride",
            str(self.val_stride),
            "--lr",
            str(self.lr),
            "--threads",
            str(self.threads),
            "--max-minutes",
            f"{minutes:.2f}",
            "--cache",
            str(CACHE),
            "--no-progress",
        ]
        return [*args, "--resume"] if resume else args

    def command(self, args: list[str]) -> list[str]:
        weights = VARIANTS[self.variant]
        if weights is None:
            return scotti_command("train", *args)
        return scotti_command("train", *args, "--loss-weights", weights)


def measure(spec: RunSpec, log: Path) -> tuple[float, int]:
    """(training windows/s, training windows at stride 1) of this config and partition."""
    out = run(
        scotti_command(
            "train",
            *spec.train_args(epochs=1, stride=2, minutes=1, resume=False),
            "--benchmark",
            "2",
        ),
        log,
        quote=False,
    )
    text = out + log.read_text()
    rate, windows = THROUGHPUT.search(text), WINDOWS.findall(text)
    if rate is None or not windows:
        msg = f"could not read the throughput from {log}"
        raise ExperimentError(msg)
    return float(rate.group(1)), int(windows[-1])


def plan(spec: RunSpec, budget_s: float, rate: float, windows: int) -> dict[str, Any]:
    """Epochs and stride so that EPOCHS epochs fit ``budget_s`` at ``rate`` windows/s."""
    # Windows one epoch may have; 0.6: validation, checkpoints and a loaded machine take
    # their share of the time the benchmark does not see.
    per_epoch = 0.6 * budget_s * rate / EPOCHS
    stride = min(MAX_STRIDE, max(2, math.ceil(windows / max(1.0, per_epoch))))
    # At the largest stride fewer epochs fit; one that does not fit is cut by --max-minutes.
    epochs = max(1, min(EPOCHS, math.floor(EPOCHS * per_epoch / (windows / stride))))
    return {
        "config": spec.config,
        "variant": spec.variant,
        "loss_weights": VARIANTS[spec.variant] or "0.01,1,1",
        "partition": spec.partition.name,
        "budget_s": budget_s,
        "measured_windows_per_s": rate,
        "train_windows_stride_1": windows,
        "epochs": epochs,
        "stride": stride,
        "trained_s": 0.0,
        "status": "planned",
        "commands": [],
    }


def train(spec: RunSpec, budget_s: float, rate: float, windows: int, log: Path) -> dict[str, Any]:
    """Train (or resume) until the planned epochs are done or this call's time is spent."""
    path = spec.run_dir / "plan.json"
    state = read_json(path) if path.is_file() else plan(spec, budget_s, rate, windows)
    if state["status"] == "done" or state["status"].startswith("failed"):
        return state
    # A larger budget than the run was planned with continues it (same epochs and stride:
    # the schedule resumes where it stopped); a smaller one never takes time back.
    state["budget_s"] = max(state["budget_s"], budget_s)
    left = state["budget_s"] - state["trained_s"]
    if left <= 5:
        state["status"] = "budget spent"
        write_json(path, state)
        return state
    resume = (spec.run_dir / "last.pt").is_file()
    args = spec.train_args(
        epochs=state["epochs"], stride=state["stride"], minutes=left / 60.0, resume=resume
    )
    cmd = spec.command(args)
    started = time.monotonic()
    try:
        run(cmd, log)
        failed = None
    except ExperimentError as exc:  # e.g. a diverging loss: the others go on, the doc says so
        failed = str(exc)
    state["trained_s"] += time.monotonic() - started
    state["commands"].append(shown(cmd))
    history = _history(spec.run_dir)
    state["epochs_done"] = len(history)
    state["status"] = "done" if len(history) >= state["epochs"] else "stopped"
    if failed is not None:
        state["status"] = f"failed: {failed.rsplit(': ', 1)[-1]}"
    write_json(path, state)
    return state


def export_command(run_dir: Path, onnx: Path, *, int8: bool = False) -> list[str]:
    """``scotti export`` of the run's last.pt; ``--force``: an export older than the
    checkpoint (the run trained on since) is replaced."""
    int8_flag = ["--int8"] if int8 else []
    return scotti_command("export", run_dir / "last.pt", "-o", onnx, *int8_flag, "--force")


def export(run_dir: Path, onnx: Path, log: Path, *, int8: bool = False) -> Path:
    """last.pt -> ONNX (checked against torch by scotti export); skipped when up to date."""
    ckpt = run_dir / "last.pt"
    cmd = export_command(run_dir, onnx, int8=int8)
    if onnx.is_file() and onnx.stat().st_mtime > ckpt.stat().st_mtime:
        COMMANDS.append(shown(cmd))  # made by an earlier call: still what made the file
        return onnx
    onnx.parent.mkdir(parents=True, exist_ok=True)
    run(cmd, log)
    return onnx


def _history(run_dir: Path) -> list[dict[str, Any]]:
    path = run_dir / "history.jsonl"
    if not path.is_file():
        return []
    return [json.loads(x) for x in path.read_text().splitlines() if x.strip()]
