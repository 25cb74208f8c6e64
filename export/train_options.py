"""What a training run is asked to do: ``scotti train``'s options as one frozen value,
saved in every checkpoint (``options``) so a resumed run can say how it was made."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

from scotti.export.losses import LossWeights
from scotti.export.tempo import DEFAULT_RANGE as DEFAULT_TEMPO_RANGE
from scotti.export.tempo import EXTRA_RANGE as EXTRA_TEMPO_RANGE


@dataclass(frozen=True)
class TrainOptions:
    epochs: int = 10  # at most; a validation plateau (patience) may end the run sooner
    batch: int = 32  # windows per optimiser step and rank (a step may run up to chunk-1 over)
    chunk: int = 8  # consecutive windows that share one pass of their frames through the CNN
    stride: int = 2  # slots between the starts of windows in an epoch (random phase per epoch)
    val_stride: int = 4  # the same for validation (fixed phase 0)
    lr: float = 1e-4
    weight_decay: float = 1e-4
    warmup_fraction: float = 0.05  # of all steps, linear warmup before the cosine decay
    grad_clip: float = 1.0  # max global gradient norm; 0 turns clipping off
    max_shift: int = 2  # taxels, random shift of each foot per chunk (0 = no augmentation)
    max_crosstalk: float = 0.0  # crosstalk added per chunk and foot, up to this (augment.py)
    sensor_transfer: float = 0.0  # share of chunks read through a drawn foreign insole
    tempo_stretch: float = 0.0  # share of chunks played at a drawn tempo (export/tempo.py)
    tempo_range: tuple[float, float] = DEFAULT_TEMPO_RANGE  # log-uniform between these
    tempo_extra: float = 0.0  # a further share of chunks at a tempo from tempo_extra_range
    tempo_extra_range: tuple[float, float] = EXTRA_TEMPO_RANGE
    seed: int = 0
    max_minutes: float = 0.0  # stop (and checkpoint) after this much training; 0 = no limit
    save_minutes: float = 10.0  # write last.pt after this much training since the last; 0 = off
    progress_bar: bool = True
    loss_weights: LossWeights = field(default_factory=LossWeights)
    freeze: tuple[str, ...] = ()  # parts kept as they are (FREEZE_GROUPS), e.g. to fine-tune
    precision: str = "fp32"  # or "bf16": autocast of the forward pass (devices.py)
    workers: int = 1  # threads building batches ahead of the step; 0 = in the loop
    patience: int = 4  # epochs without a validation improvement before stopping; 0 = never
    min_delta: float = 1e-3  # what counts as an improvement of the validation loss
    ema: float = 0.0  # decay of an exponential moving average of the weights; 0 = off
    keep_near: float = 0.0  # weight of the pull of pooled vectors to --init's (anchor.py); 0 = off
    keep_near_pass: str = "eval"  # which passes it compares: "eval" or "matched" (anchor.py)
    # "batch": the frame CNN's batch norm normalises by each batch and its running
    # statistics follow; "kept": it runs on the statistics it has, as at inference.
    # scotti train picks "kept" for --init weights with a graph's folded statistics.
    norm_statistics: str = "batch"

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


NORM_STATISTICS = ("batch", "kept")
