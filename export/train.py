"""Training SCOTTI: chunked embeddings, Adam with warmup + cosine, exact resume.

A step takes ``batch`` windows as a few chunks of ``chunk`` consecutive
windows. The CNN sees each frame of a chunk once; the chunk's windows are
then views (unfold) of its embeddings. This is exact because the CNN works
per frame, and it cuts the CNN's work from T frames per window to about
stride + T/chunk (export/TRAINING.md has the measured gain).

Everything random in an epoch (window phase, chunk cuts, order, shifts) is
drawn from a generator seeded with (seed, epoch); dropout uses torch's
generator, whose state the checkpoint keeps. So a run stopped after any
step and resumed from its checkpoint continues exactly as if never stopped.
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from scotti.export.augment import draw_shifts, shift_feet
from scotti.export.checkpoint import save_checkpoint
from scotti.export.errors import ExportError
from scotti.export.evaluate import chunked_outputs, evaluate, to_targets
from scotti.export.losses import LossWeights, ScottiTargets, scotti_loss
from scotti.export.model import Scotti
from scotti.export.windows import Chunk, WindowDataset
from tqdm import tqdm

log = logging.getLogger(__name__)


class TrainingDivergedError(ExportError):
    """The loss became NaN or infinite (learning rate too high, or broken labels)."""


@dataclass(frozen=True)
class TrainOptions:
    epochs: int = 10
    batch: int = 32  # windows per optimiser step (a step may run up to chunk-1 over)
    chunk: int = 8  # consecutive windows that share one pass of their frames through the CNN
    stride: int = 2  # slots between the starts of windows in an epoch (random phase per epoch)
    val_stride: int = 4  # the same for validation (fixed phase 0)
    lr: float = 1e-4
    weight_decay: float = 1e-4
    warmup_fraction: float = 0.05  # of all steps, linear warmup before the cosine decay
    grad_clip: float = 1.0  # max global gradient norm; 0 turns clipping off
    max_shift: int = 2  # taxels, random shift of each foot per chunk (0 = no augmentation)
    seed: int = 0
    max_minutes: float = 0.0  # stop (and checkpoint) after this much training; 0 = no limit
    progress_bar: bool = True
    loss_weights: LossWeights = field(default_factory=LossWeights)
    freeze: tuple[str, ...] = ()  # parts kept as they are (FREEZE_GROUPS), e.g. to fine-tune

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


# Parts of the model that fine-tuning may keep fixed: the per-frame CNN, and the
# encoder (class token, positions, transformer layers, final norm, pooling).
FREEZE_GROUPS = ("cnn", "encoder")


def freeze_parts(model: Scotti, groups: Sequence[str]) -> list[torch.nn.Module]:
    """Stop gradients into the named parts; returns their modules (kept in eval mode
    while training, so batch-norm statistics and dropout stay as they were)."""
    unknown = sorted(set(groups) - set(FREEZE_GROUPS))
    if unknown:
        msg = f"cannot freeze {', '.join(unknown)}: the parts are {', '.join(FREEZE_GROUPS)}"
        raise ExportError(msg)
    modules: list[torch.nn.Module] = []
    params: list[torch.nn.Parameter] = []
    if "cnn" in groups:
        modules.append(model.cnn)
        params += list(model.cnn.parameters())
    if "encoder" in groups:
        modules += [model.encoder, model.ln_final]
        params += [model.class_token, model.positions, model.pool_weights]
        params += list(model.encoder.parameters()) + list(model.ln_final.parameters())
    for p in params:
        p.requires_grad_(False)
    return modules


def load_initial_weights(model: Scotti, state: dict[str, torch.Tensor]) -> list[str]:
    """Start from another run's weights (``--init``); returns what could not be copied whole.

    The action head may have grown since the checkpoint (the contract appends
    actions at the end): its rows for the actions both know are copied, the new
    ones keep their fresh initialisation. Any other difference is an error.
    """
    own = model.state_dict()
    notes: list[str] = []
    missing = sorted(set(own) - set(state))
    unexpected = sorted(set(state) - set(own))
    if missing or unexpected:
        msg = f"--init checkpoint does not fit this model (missing {missing[:3]}, extra "
        msg += f"{unexpected[:3]})"
        raise ExportError(msg)
    merged: dict[str, torch.Tensor] = {}
    for name, value in state.items():
        mine = own[name]
        if value.shape == mine.shape:
            merged[name] = value
        elif (
            name.startswith("action_head.")
            and value.shape[1:] == mine.shape[1:]
            and value.shape[0] < mine.shape[0]
        ):
            grown = mine.clone()
            grown[: value.shape[0]] = value
            merged[name] = grown
            notes.append(f"{name}: {value.shape[0]} of {mine.shape[0]} rows from the checkpoint")
        else:
            msg = f"--init checkpoint's {name} is {tuple(value.shape)}, this model's "
            msg += f"{tuple(mine.shape)}"
            raise ExportError(msg)
    model.load_state_dict(merged)
    return notes


@dataclass(frozen=True)
class PlannedChunk:
    chunk: Chunk
    shifts: np.ndarray  # (2, 2) (rows, cols) per foot


def plan_epoch(dataset: WindowDataset, opts: TrainOptions, epoch: int) -> list[list[PlannedChunk]]:
    """The epoch's batches, a pure function of (dataset, options, seed, epoch)."""
    rng = np.random.default_rng([opts.seed, epoch])
    phase = int(rng.integers(opts.stride))
    chunks = dataset.chunks(stride=opts.stride, chunk=opts.chunk, phase=phase, rng=rng)
    batches: list[list[PlannedChunk]] = []
    current: list[PlannedChunk] = []
    windows = 0
    for i in rng.permutation(len(chunks)):
        current.append(PlannedChunk(chunks[i], draw_shifts(rng, opts.max_shift)))
        windows += chunks[i].count
        if windows >= opts.batch:
            batches.append(current)
            current, windows = [], 0
    if current:
        batches.append(current)
    return batches


def batch_tensors(
    dataset: WindowDataset, batch: Sequence[PlannedChunk]
) -> tuple[list[torch.Tensor], ScottiTargets]:
    """Shifted frames (float32 counts) per chunk and the batch's targets."""
    cols = dataset.sessions[0].frames.shape[2] // 2
    frames = [
        torch.from_numpy(shift_feet(dataset.frames(p.chunk), p.shifts, cols).astype(np.float32))
        for p in batch
    ]
    return frames, to_targets([dataset.targets(p.chunk) for p in batch])


def warmup_cosine(total_steps: int, warmup_fraction: float) -> Callable[[int], float]:
    """LR factor: linear from ~0 to 1 over the warmup, then cosine down to 0 at the end."""
    warmup = max(1, round(warmup_fraction * total_steps))

    def factor(step: int) -> float:
        if step < warmup:
            return (step + 1) / warmup
        done = min(1.0, (step - warmup) / max(1, total_steps - warmup))
        return 0.5 * (1.0 + math.cos(math.pi * done))

    return factor


@dataclass
class TrainState:
    """Where a run is: completed epochs, steps into the current one, and history."""

    epoch: int = 0
    step_in_epoch: int = 0
    global_step: int = 0
    history: list[dict[str, Any]] = field(default_factory=list)
    best_loss: float = math.inf
    # running sums of the epoch in progress (kept so a mid-epoch resume reports the same)
    epoch_loss_sum: float = 0.0
    epoch_windows: int = 0


class Trainer:
    """Owns the model, optimiser and schedule of one run; ``fit`` trains to the end."""

    def __init__(
        self,
        model: Scotti,
        train_set: WindowDataset,
        test_set: WindowDataset | None,
        opts: TrainOptions,
        *,
        run_dir: Path | None = None,
        training_data: dict[str, Any] | None = None,
    ) -> None:
        self.model = model
        self.train_set = train_set
        self.test_set = test_set
        self.opts = opts
        self.run_dir = run_dir
        self.training_data = training_data or {}
        self.window = model.cfg.window
        self.frozen = freeze_parts(model, opts.freeze)
        self.optimizer = torch.optim.Adam(
            [p for p in model.parameters() if p.requires_grad],
            lr=opts.lr,
            weight_decay=opts.weight_decay,
        )
        self.total_steps = max(1, opts.epochs * len(plan_epoch(train_set, opts, 0)))
        self.scheduler = torch.optim.lr_scheduler.LambdaLR(
            self.optimizer, warmup_cosine(self.total_steps, opts.warmup_fraction)
        )
        self.state = TrainState()
        self.last_metrics: dict[str, Any] = {}
        self.step_losses: list[float] = []  # every step's loss in this process, for tests

    # --- one step ------------------------------------------------------------

    def train_step(self, batch: Sequence[PlannedChunk]) -> tuple[float, int]:
        """One optimiser step; returns the batch's mean loss and its window count."""
        self.model.train()
        for module in self.frozen:
            module.eval()  # frozen: batch-norm statistics and dropout as they were
        frames, targets = batch_tensors(self.train_set, batch)
        outputs = chunked_outputs(self.model, frames, self.window, self.opts.stride)
        loss, _ = scotti_loss(outputs, targets, self.opts.loss_weights)
        if not torch.isfinite(loss):
            msg = (
                f"loss is {float(loss.detach())} at step {self.state.global_step + 1}: lower --lr, "
                f"or resume from the last checkpoint"
            )
            raise TrainingDivergedError(msg)
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()  # type: ignore[no-untyped-call]
        if self.opts.grad_clip > 0:
            trainable = [p for p in self.model.parameters() if p.requires_grad]
            torch.nn.utils.clip_grad_norm_(trainable, self.opts.grad_clip)
        self.optimizer.step()
        self.scheduler.step()
        return float(loss.detach()), int(targets.action.shape[0])

    # --- the loop --------------------------------------------------------------

    def fit(self, max_steps: int = 0) -> str:
        """Train until ``epochs`` are done ("done"), or stop with a checkpoint ("stopped").

        A run stops early when ``max_minutes`` run out or after ``max_steps``
        steps of this call (0: no limit).
        """
        opts, st = self.opts, self.state
        started = time.monotonic()
        steps = 0
        while st.epoch < opts.epochs:
            batches = plan_epoch(self.train_set, opts, st.epoch)
            windows_total = sum(p.chunk.count for b in batches for p in b)
            bar = tqdm(
                total=windows_total,
                initial=st.epoch_windows,
                unit="win",
                desc=f"epoch {st.epoch + 1}/{opts.epochs}",
                disable=not opts.progress_bar,
                leave=False,
            )
            epoch_started = time.monotonic()
            windows_now = 0
            with bar:
                for batch in batches[st.step_in_epoch :]:
                    out_of_time = 0 < 60.0 * opts.max_minutes < time.monotonic() - started
                    if out_of_time or 0 < max_steps <= steps:
                        log.info("stopping at epoch %d step %d", st.epoch + 1, st.step_in_epoch)
                        self.save("last.pt")
                        return "stopped"
                    loss, n = self.train_step(batch)
                    self.step_losses.append(loss)
                    steps += 1
                    st.step_in_epoch += 1
                    st.global_step += 1
                    st.epoch_loss_sum += loss * n
                    st.epoch_windows += n
                    windows_now += n
                    bar.update(n)
                    rate = windows_now / max(1e-9, time.monotonic() - epoch_started)
                    bar.set_postfix(loss=f"{loss:.3f}", win_s=f"{rate:.1f}", refresh=False)
            seconds = time.monotonic() - epoch_started
            self._end_epoch(windows_now / max(1e-9, seconds), seconds)
        return "done"

    def _end_epoch(self, windows_per_s: float, seconds: float) -> None:
        st = self.state
        record: dict[str, Any] = {
            "epoch": st.epoch + 1,
            "train_loss": st.epoch_loss_sum / max(1, st.epoch_windows),
            "train_windows": st.epoch_windows,
            "windows_per_s": windows_per_s,
            "seconds": seconds,
            "lr": float(self.scheduler.get_last_lr()[0]),
        }
        if self.test_set is not None and self.test_set.count(self.opts.val_stride) > 0:
            record["val"] = evaluate(
                self.model, self.test_set, self.opts.val_stride, self.opts.loss_weights
            )
        self.last_metrics = record
        st.history.append(record)
        st.epoch += 1
        st.step_in_epoch = 0
        st.epoch_loss_sum, st.epoch_windows = 0.0, 0
        val = record.get("val", {})
        log.info(
            "epoch %d: loss %.4f, %.1f windows/s%s",
            record["epoch"],
            record["train_loss"],
            windows_per_s,
            "".join(f", val {k} {v:.4g}" for k, v in val.items() if isinstance(v, float)),
        )
        score = float(val.get("loss", record["train_loss"]))
        self.save("last.pt")
        if self.run_dir is not None:
            with (self.run_dir / "history.jsonl").open("w") as f:
                f.writelines(json.dumps(r) + "\n" for r in st.history)
        if score < st.best_loss:
            st.best_loss = score
            self.save("best.pt")

    # --- checkpoints -------------------------------------------------------------

    def checkpoint(self) -> dict[str, Any]:
        st = self.state
        return {
            "config": self.model.cfg.to_dict(),
            "model": self.model.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "scheduler": self.scheduler.state_dict(),
            "epoch": st.epoch,
            "step_in_epoch": st.step_in_epoch,
            "global_step": st.global_step,
            "total_steps": self.total_steps,
            "rng": {"torch": torch.get_rng_state()},  # numpy draws: seeded by (seed, epoch)
            "options": self.opts.to_dict(),
            "training_data": self.training_data,
            "metrics": self.last_metrics,
            "history": st.history,
            "best_loss": st.best_loss,
            "running": {"loss_sum": st.epoch_loss_sum, "windows": st.epoch_windows},
        }

    def save(self, name: str) -> None:
        if self.run_dir is not None:
            save_checkpoint(self.checkpoint(), self.run_dir / name)

    def restore(self, ckpt: dict[str, Any]) -> None:
        """Continue from ``ckpt`` (model, optimiser, schedule, position, torch RNG)."""
        self.model.load_state_dict(ckpt["model"])
        self.optimizer.load_state_dict(ckpt["optimizer"])
        self.scheduler.load_state_dict(ckpt["scheduler"])
        self.state = TrainState(
            epoch=int(ckpt["epoch"]),
            step_in_epoch=int(ckpt["step_in_epoch"]),
            global_step=int(ckpt["global_step"]),
            history=list(ckpt.get("history", [])),
            best_loss=float(ckpt.get("best_loss", math.inf)),
            epoch_loss_sum=float(ckpt["running"]["loss_sum"]),
            epoch_windows=int(ckpt["running"]["windows"]),
        )
        self.last_metrics = dict(ckpt.get("metrics", {}))
        torch.set_rng_state(ckpt["rng"]["torch"])


def measure_throughput(
    model: Scotti, dataset: WindowDataset, opts: TrainOptions, steps: int = 5
) -> dict[str, float]:
    """Training windows/s (forward + backward) the naive way and chunked, same batches.

    Naive: every window's T frames go through the CNN on their own, as
    ``model(frames (B, T, H, 2W))`` does. Chunked: ``chunked_outputs``. The
    two alternate batch by batch, so a machine whose load changes meanwhile
    slows both alike.
    """
    batches = plan_epoch(dataset, opts, 0)[: steps + 1]
    window = model.cfg.window
    model.train()
    seconds = {"naive": 0.0, "chunked": 0.0}
    windows = 0
    for i, batch in enumerate(batches):
        frames, targets = batch_tensors(dataset, batch)
        for way in seconds:
            started = time.perf_counter()
            if way == "naive":
                stacked = [unfold_frames(f, window, opts.stride) for f in frames]
                outputs = model(torch.cat(stacked))  # (B, T, H, 2W) in
            else:
                outputs = chunked_outputs(model, frames, window, opts.stride)
            loss, _ = scotti_loss(outputs, targets, opts.loss_weights)
            model.zero_grad(set_to_none=True)
            loss.backward()  # type: ignore[no-untyped-call]
            if i > 0:  # the first batch warms up allocators and kernels: not counted
                seconds[way] += time.perf_counter() - started
        windows += int(targets.action.shape[0]) if i > 0 else 0
    rates = {way: windows / max(1e-9, s) for way, s in seconds.items()}
    rates["ratio"] = rates["chunked"] / max(1e-9, rates["naive"])
    return rates


def unfold_frames(frames: torch.Tensor, window: int, stride: int) -> torch.Tensor:
    """Frames (L, H, 2W) -> windows of frames (K, T, H, 2W), copied: the naive layout."""
    return frames.unfold(0, window, stride).permute(0, 3, 1, 2).contiguous()
