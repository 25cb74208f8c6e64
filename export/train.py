"""Training SCOTTI: chunked embeddings, Adam with warmup + cosine, exact resume,
any device, several processes, early stopping on a validation plateau.

A step takes ``batch`` windows as a few chunks of ``chunk`` consecutive
windows. The CNN sees each frame of a chunk once; the chunk's windows are
then views (unfold) of its embeddings. This is exact because the CNN works
per frame, and it cuts the CNN's work from T frames per window to about
stride + T/chunk (export/TRAINING.md has the measured gain).

Everything random in an epoch is drawn from a generator seeded with (seed,
epoch) (export/epochs.py); dropout uses torch's generator, whose state the
checkpoint keeps. So a run stopped after any step and resumed from its
checkpoint continues exactly as if never stopped. Batches are built ahead
in background threads (export/prefetch.py) without changing any number;
under torchrun each rank takes its share of the plan (export/distributed.py).

A run stops cleanly with a checkpoint when ``max_minutes`` run out or on
SIGTERM/SIGINT (export/stop_signals.py), and writes ``last.pt`` every
``save_minutes`` besides, so a process killed without warning loses at most
that much training.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from contextlib import closing
from pathlib import Path
from typing import Any

import torch
from scotti.export import distributed
from scotti.export.anchor import Anchor
from scotti.export.checkpoint import save_checkpoint
from scotti.export.devices import autocast, batch_to_device, pin_batch
from scotti.export.distributed import DistContext
from scotti.export.early_stop import plateau
from scotti.export.epoch_log import log_epoch, write_history
from scotti.export.epochs import PlannedChunk, batch_tensors, plan_epoch, warmup_cosine
from scotti.export.errors import ExportError
from scotti.export.evaluate import chunked_outputs_pooled, evaluate
from scotti.export.finetune import FREEZE_GROUPS, freeze_parts, kept_norm, load_initial_weights
from scotti.export.losses import ScottiTargets, scotti_loss
from scotti.export.model import Scotti, ScottiOutputs
from scotti.export.optimizer import adam, load_optimizer_state
from scotti.export.prefetch import prefetched
from scotti.export.rng_state import RngState, rng_state, set_rng_state
from scotti.export.stop_signals import StopRequest
from scotti.export.throughput import measure_throughput, unfold_frames
from scotti.export.train_options import TrainOptions
from scotti.export.train_state import TrainState, as_values, from_values
from scotti.export.watch import Watched, watch_record
from scotti.export.windows import WindowDataset
from torch.optim.swa_utils import AveragedModel, get_ema_multi_avg_fn
from tqdm import tqdm

# The pieces that moved into their own modules, still importable from here.
__all__ = [
    "FREEZE_GROUPS",
    "PlannedChunk",
    "TrainOptions",
    "Trainer",
    "TrainingDivergedError",
    "adam",
    "batch_tensors",
    "freeze_parts",
    "load_initial_weights",
    "load_optimizer_state",
    "measure_throughput",
    "plan_epoch",
    "unfold_frames",
    "warmup_cosine",
]

log = logging.getLogger(__name__)


class TrainingDivergedError(ExportError):
    """The loss became NaN or infinite (learning rate too high, or broken labels)."""


class ChunkedWindows(torch.nn.Module):
    """The training forward pass as one module's ``forward``, so DDP's hooks see it: the
    heads' outputs and the pooled vectors they read (which --keep-near-pass matched holds)."""

    def __init__(self, model: Scotti, stride: int) -> None:
        super().__init__()
        self.model = model
        self.stride = stride

    def forward(self, frames: list[torch.Tensor]) -> tuple[ScottiOutputs, torch.Tensor]:
        return chunked_outputs_pooled(self.model, frames, self.model.cfg.window, self.stride)


class Trainer:
    """Owns the model, optimiser and schedule of one run; ``fit`` trains to the end."""

    def __init__(
        self,
        model: Scotti,
        train_set: WindowDataset,
        val_set: WindowDataset | None,
        opts: TrainOptions,
        *,
        run_dir: Path | None = None,
        training_data: dict[str, Any] | None = None,
        device: torch.device | None = None,
        dist_ctx: DistContext | None = None,
        watched: Sequence[Watched] = (),
        anchor: Anchor | None = None,
    ) -> None:
        self.device = device or torch.device("cpu")
        # --keep-near: the pull of the pooled vectors towards the initial weights' (anchor.py)
        self.anchor = anchor.to(self.device) if anchor is not None else None
        self.anchor_terms: list[float] = []  # every step's term in this process, for tests
        self.watched = list(watched)  # scored after every epoch (export/watch.py)
        self.dist = dist_ctx or DistContext()
        self.model = model.to(self.device)
        self.train_set = train_set
        self.val_set = val_set
        self.opts = opts
        self.run_dir = run_dir
        self.training_data = training_data or {}
        self.frozen = freeze_parts(model, opts.freeze)
        if opts.norm_statistics == "kept":
            self.frozen.append(kept_norm(model))
        self.forward = distributed.wrap(ChunkedWindows(model, opts.stride), self.dist, self.device)
        self.optimizer = adam(
            [p for p in model.parameters() if p.requires_grad],
            self.device,
            lr=opts.lr,
            weight_decay=opts.weight_decay,
        )
        self.total_steps = max(1, opts.epochs * len(self.epoch_batches(0)))
        self.scheduler = torch.optim.lr_scheduler.LambdaLR(
            self.optimizer, warmup_cosine(self.total_steps, opts.warmup_fraction)
        )
        # With --ema, validation, best.pt and export see the moving average of the weights
        # (the epoch-to-epoch wander of the raw weights is what makes validation noisy);
        # the raw weights go on training and are kept beside it for --resume.
        self.averaged = (
            AveragedModel(
                model,
                multi_avg_fn=get_ema_multi_avg_fn(opts.ema),  # type: ignore[no-untyped-call]
                use_buffers=True,
            )
            if opts.ema > 0
            else None
        )
        self.state = TrainState()
        self.last_metrics: dict[str, Any] = {}
        self.step_losses: list[float] = []  # every step's loss in this process, for tests
        self.saved_at = time.monotonic()  # when last.pt was last written (or the run began)

    def epoch_batches(self, epoch: int) -> list[list[PlannedChunk]]:
        """This rank's batches of the epoch (all of them in a single process)."""
        return distributed.shard(plan_epoch(self.train_set, self.opts, epoch), self.dist)

    def _build(self, batch: list[PlannedChunk]) -> tuple[list[torch.Tensor], ScottiTargets]:
        """A batch's tensors on the CPU, pinned for a GPU (runs in a prefetch thread)."""
        return pin_batch(*batch_tensors(self.train_set, batch), self.device)

    # --- one step ------------------------------------------------------------

    def train_step(self, frames: list[torch.Tensor], targets: ScottiTargets) -> tuple[float, int]:
        """One optimiser step; returns the mean loss and the window count over all ranks."""
        pull = self._anchor_pull(frames)  # before the training pass: it runs in eval mode
        self.model.train()
        for module in self.frozen:
            module.eval()  # frozen: batch-norm statistics and dropout as they were
        matched = self.anchor is not None and self.anchor.matched
        rng_before = rng_state(self.device) if matched else None  # the masks it replays
        with autocast(self.device, self.opts.precision):
            outputs, pooled = self.forward(frames)
            if rng_before is not None:
                pull = self._matched_pull(frames, pooled, rng_before)
        # The loss in float32 whatever the forward pass ran in (a no-op for fp32).
        outputs = ScottiOutputs(*(o.float() for o in outputs))
        loss, _ = scotti_loss(outputs, targets, self.opts.loss_weights)
        if pull is not None:
            loss = loss + pull
        if not torch.isfinite(loss):
            msg = (
                f"loss is {float(loss.detach())} at step {self.state.global_step + 1}: lower --lr, "
                f"or resume from the last checkpoint"
            )
            raise TrainingDivergedError(msg)
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()  # type: ignore[no-untyped-call]  # DDP averages the gradients here
        if self.opts.grad_clip > 0:
            trainable = [p for p in self.model.parameters() if p.requires_grad]
            torch.nn.utils.clip_grad_norm_(trainable, self.opts.grad_clip)
        self.optimizer.step()
        self.scheduler.step()
        if self.averaged is not None:
            self.averaged.update_parameters(self.model)
        n = int(targets.action.shape[0])
        if not self.dist.distributed:
            return float(loss.detach()), n
        loss_sum, windows = distributed.all_sum(
            [float(loss.detach()) * n, n], self.dist, self.device
        )
        return loss_sum / windows, int(windows)

    def _anchor_pull(self, frames: list[torch.Tensor]) -> torch.Tensor | None:
        """--keep-near-pass eval's weighted term for this batch (None otherwise), recorded."""
        if self.anchor is None or self.anchor.matched:
            return None
        with autocast(self.device, self.opts.precision):  # a dropout-free pass (anchor.py)
            term = self.anchor.term(self.model, frames, self.opts.stride)
        return self._recorded(term)

    def _matched_pull(
        self, frames: list[torch.Tensor], pooled: torch.Tensor, rng_before: RngState
    ) -> torch.Tensor:
        """--keep-near-pass matched's weighted term, recorded: the training pass's pooled
        vectors against the reference's replay of it (anchor.py)."""
        assert self.anchor is not None
        term = self.anchor.matched_term(self.model, frames, self.opts.stride, pooled, rng_before)
        return self._recorded(term)

    def _recorded(self, term: torch.Tensor) -> torch.Tensor:
        assert self.anchor is not None
        self.anchor_terms.append(float(term.detach()))
        self.state.epoch_anchor_sum += self.anchor_terms[-1]
        return self.anchor.weight * term

    # --- the loop --------------------------------------------------------------

    def fit(self, max_steps: int = 0, stop: StopRequest | None = None) -> str:
        """Train until ``epochs`` are done ("done"), the validation loss has reached its
        plateau ("plateau"), or stop with a checkpoint ("stopped").

        A run stops early, between two steps, when ``max_minutes`` run out or ``stop``
        is requested (on any rank: all ranks stop together), or after ``max_steps``
        steps of this call (0: no limit).
        """
        opts, st = self.opts, self.state
        started = time.monotonic()
        self.saved_at = started
        steps = 0
        while st.epoch < opts.epochs:
            if self.plateau_reached():
                return "plateau"  # resumed from a run that had already reached it
            batches = self.epoch_batches(st.epoch)
            windows_total = sum(p.chunk.count for b in batches for p in b) * self.dist.world_size
            bar = tqdm(
                total=windows_total,
                initial=st.epoch_windows,
                unit="win",
                desc=f"epoch {st.epoch + 1}/{opts.epochs}",
                disable=not opts.progress_bar or not self.dist.is_main,
                leave=False,
            )
            epoch_started = time.monotonic()
            windows_now = 0
            ready = prefetched(batches[st.step_in_epoch :], self._build, opts.workers)
            with bar, closing(ready):
                for built in ready:
                    why, save_due = self._stop_or_save(started, stop)
                    if why is None and 0 < max_steps <= steps:
                        why = f"{max_steps} steps"
                    if why is not None:
                        self._stop(why)
                        return "stopped"
                    if save_due:
                        self.save("last.pt")
                    loss, n = self.train_step(*batch_to_device(*built, self.device))
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
        return "plateau" if self.plateau_reached() else "done"

    def _stop_or_save(self, started: float, stop: StopRequest | None) -> tuple[str | None, bool]:
        """Why to stop before the next step (None: go on), and whether last.pt is due.

        Under torchrun every rank asks its own clock and signals, and all take the
        answer of any (one collective): they must stop, and save, together.
        """
        now = time.monotonic()
        out_of_time = 0 < 60.0 * self.opts.max_minutes < now - started
        signalled = stop is not None and stop.requested
        save_due = 0 < 60.0 * self.opts.save_minutes <= now - self.saved_at
        if self.dist.distributed:
            flags = [float(out_of_time), float(signalled), float(save_due)]
            out_of_time, signalled, save_due = (
                v > 0 for v in distributed.all_sum(flags, self.dist, self.device)
            )
        if out_of_time:
            return f"--max-minutes {self.opts.max_minutes:g}", False
        if signalled:  # this rank's signal, or another rank's (this one then has none)
            name = stop.signal_name if stop is not None else None
            return name or "a signal to another rank", False
        return None, save_due

    def _stop(self, why: str) -> None:
        """Write last.pt and say where the run stopped, and why."""
        self.save("last.pt")
        if self.dist.is_main:
            st = self.state
            where = self.run_dir / "last.pt" if self.run_dir is not None else "not written"
            log.info("%s: stopped at epoch %d step %d, checkpoint %s", why, st.epoch + 1,
                     st.step_in_epoch, where)  # fmt: skip

    @property
    def evaluated_model(self) -> Scotti:
        """The weights validation judges and checkpoints hand on: the average, if any."""
        if self.averaged is None:
            return self.model
        module = self.averaged.module
        assert isinstance(module, Scotti)  # AveragedModel keeps a deep copy of the model
        return module

    def plateau_reached(self) -> bool:
        return plateau(self.state.history, self.opts.patience, self.opts.min_delta).reached

    def _validate(self) -> dict[str, Any] | None:
        """Validation metrics, computed on rank 0 and handed to every rank."""
        val_set = self.val_set
        if val_set is None or val_set.count(self.opts.val_stride) == 0:
            return None
        metrics = None
        if self.dist.is_main:
            opts = self.opts
            metrics = evaluate(self.evaluated_model, val_set, opts.val_stride, opts.loss_weights)
        result: dict[str, Any] = distributed.from_main(metrics, self.dist)
        return result

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
        if self.anchor is not None:  # one process only (train_cli refuses torchrun)
            record["keep_near"] = {
                "weight": self.anchor.weight,
                "pass": "matched" if self.anchor.matched else "eval",
                "distance": st.epoch_anchor_sum / max(1, st.step_in_epoch),  # mean per step
            }
        val = self._validate()
        if val is not None:
            record["val"] = val
            where = plateau([*st.history, record], self.opts.patience, self.opts.min_delta)
            record["best_epoch"] = where.best_epoch
            record["stale_epochs"] = where.stale_epochs
            if where.reached:
                record["status"] = "plateau"
        if self.watched and self.dist.is_main:  # a look only: no figure of it steers the run
            record["watch"] = watch_record(self.evaluated_model, self.watched, self.opts.val_stride)
        if "status" not in record and st.epoch + 1 >= self.opts.epochs:
            record["status"] = "epochs done"  # the schedule's end, not a time budget
        self.last_metrics = record
        st.history.append(record)
        st.epoch += 1
        st.step_in_epoch = 0
        st.epoch_loss_sum, st.epoch_windows, st.epoch_anchor_sum = 0.0, 0, 0.0
        score = float(record["val"]["loss"] if val is not None else record["train_loss"])
        better = score < st.best_loss
        if better:
            st.best_loss = score
        self.save("last.pt", *(["best.pt"] if better else []))
        if not self.dist.is_main:
            return
        log_epoch(record, st.best_loss, self.opts.min_delta)
        if self.run_dir is not None:
            write_history(self.run_dir, st.history)

    # --- checkpoints -------------------------------------------------------------

    def checkpoint(self) -> dict[str, Any]:
        """The run as plain values (a collective under torchrun: every rank calls it)."""
        st = self.state
        distributed.sync_buffers(self.model, self.dist)
        rng: dict[str, Any] = dict(rng_state(self.device))
        if self.dist.distributed:
            rng["by_rank"] = distributed.gather(rng_state(self.device), self.dist)
        averaged = {}
        if self.averaged is not None:  # "model" is the average: what export and --init read
            averaged = {
                "trained_model": self.model.state_dict(),
                "ema_updates": int(self.averaged.n_averaged.item()),
            }
        return {
            "config": self.model.cfg.to_dict(),
            "model": self.evaluated_model.state_dict(),
            **averaged,
            "optimizer": self.optimizer.state_dict(),
            "scheduler": self.scheduler.state_dict(),
            **as_values(st),
            "total_steps": self.total_steps,
            "world_size": self.dist.world_size,
            "rng": rng,  # numpy draws: seeded by (seed, epoch)
            "options": self.opts.to_dict(),
            "training_data": self.training_data,
            "metrics": self.last_metrics,
        }

    def save(self, *names: str) -> None:
        """Write the checkpoint under each name (rank 0 only; every rank must call it).

        Reads the run's state and RNGs without changing them, so a run that saves
        more often trains to the same numbers.
        """
        ckpt = self.checkpoint()
        if self.run_dir is not None and self.dist.is_main:
            for name in names:
                save_checkpoint(ckpt, self.run_dir / name)
        if "last.pt" in names:
            self.saved_at = time.monotonic()

    def restore(self, ckpt: dict[str, Any]) -> None:
        """Continue from ``ckpt`` (model, optimiser, schedule, position, RNGs)."""
        saved_world = int(ckpt.get("world_size", 1))
        if saved_world != self.dist.world_size and int(ckpt["step_in_epoch"]) > 0:
            msg = (
                f"the checkpoint stopped mid-epoch with {saved_world} process(es): resume it "
                f"with {saved_world}, or from a checkpoint at an epoch's end"
            )
            raise ExportError(msg)
        self.model.load_state_dict(ckpt.get("trained_model", ckpt["model"]))
        if self.averaged is not None and "trained_model" in ckpt:
            self.averaged.module.load_state_dict(ckpt["model"])
            self.averaged.n_averaged.fill_(int(ckpt["ema_updates"]))
        # A run resumed with --ema that had none starts its average at the next step.
        load_optimizer_state(self.optimizer, ckpt["optimizer"])
        self.scheduler.load_state_dict(ckpt["scheduler"])
        self.state = from_values(ckpt)
        self.last_metrics = dict(ckpt.get("metrics", {}))
        rng = ckpt["rng"]
        by_rank = rng.get("by_rank")
        if isinstance(by_rank, list) and len(by_rank) == self.dist.world_size:
            rng = by_rank[self.dist.rank]
        set_rng_state(rng, self.device)
