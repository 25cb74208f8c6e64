"""Sensor effects without memory: noise, crosstalk, broken lines.

Stages act on a chunk of frames ``(n, 2, 32, 22)`` (axis 1: 0 left, 1 right)
in float counts, after the insole's transfer curve. Cells outside the insole
outline are no taxels and stay 0. Gain spread, threshold and transfer curve
belong to the insole itself (``scotti.sim.insole``), not to effects.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import Field
from scotti.models.contract import FRAME_COLS, FRAME_ROWS, MAX_COUNT
from scotti.sim.effects.base import EffectParams, count_call


class NoiseParams(EffectParams):
    """Read noise of the ADC and amplifier, white Gaussian in counts.

    Typical 2-10 counts on a 12-bit scan; 0..200 accepted.
    """

    std_counts: float = Field(6.0, ge=0.0, le=200.0)


class CrosstalkParams(EffectParams):
    """Ghosting of a passive row-column array: sneak currents through other taxels.

    Each taxel reads ``fraction * (mean of its row + mean of its column)``
    on top of its own value. Typical 0.01-0.05; 0..0.5.
    """

    fraction: float = Field(0.02, ge=0.0, le=0.5)


class DeadLineParams(EffectParams):
    """A broken row or column line of one insole.

    ``kind="dead"``: an open line reads 0; ``kind="shorted"``: a line
    shorted to the reference reads full scale wherever there is a taxel.
    """

    foot: Literal["left", "right"] = "left"
    axis: Literal["row", "column"] = "row"
    index: int = Field(0, ge=0, le=max(FRAME_ROWS, FRAME_COLS) - 1)
    kind: Literal["dead", "shorted"] = "dead"


FOOT_INDEX = {"left": 0, "right": 1}


class Noise:
    domain = "counts"

    def __init__(self, params: NoiseParams, rng: np.random.Generator, mask: np.ndarray) -> None:
        self.std = np.float32(params.std_counts)
        self.rng = rng
        self.mask = mask

    def apply(self, x: np.ndarray) -> np.ndarray:
        count_call("noise")
        noise = self.rng.standard_normal(x.shape, dtype=np.float32) * self.std
        return np.asarray(x + noise * self.mask)


class Crosstalk:
    domain = "counts"

    def __init__(self, params: CrosstalkParams, mask: np.ndarray) -> None:
        self.fraction = np.float32(params.fraction)
        self.mask = mask

    def apply(self, x: np.ndarray) -> np.ndarray:
        count_call("crosstalk")
        rows = x.mean(axis=3, keepdims=True)  # (n, 2, 32, 1)
        cols = x.mean(axis=2, keepdims=True)  # (n, 2, 1, 22)
        return np.asarray(x + self.fraction * (rows + cols) * self.mask)


class DeadLine:
    domain = "counts"

    def __init__(self, params: DeadLineParams, mask: np.ndarray) -> None:
        self.foot = FOOT_INDEX[params.foot]
        limit = FRAME_ROWS if params.axis == "row" else FRAME_COLS
        self.index = min(params.index, limit - 1)
        self.axis = params.axis
        self.value = 0.0 if params.kind == "dead" else float(MAX_COUNT)
        self.mask = mask

    def apply(self, x: np.ndarray) -> np.ndarray:
        count_call("dead_line")
        out = x.copy()
        if self.axis == "row":
            out[:, self.foot, self.index, :] = self.value * self.mask[self.index, :]
        else:
            out[:, self.foot, :, self.index] = self.value * self.mask[:, self.index]
        return out
