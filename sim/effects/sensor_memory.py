"""Sensor effects with memory: hysteresis and creep of the piezoresistive film.

Both act on pressure (kPa) before the transfer curve and carry their state
from one chunk of frames to the next, so a session rendered in chunks equals
one rendered whole.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field
from scotti.sim.effects.base import EffectParams, count_call


class HysteresisParams(EffectParams):
    """Unloading reads higher than loading at the same pressure.

    The film remembers its recent peak: an envelope follows the pressure up
    at once and back down with time constant ``tau_s``; the reading is
    ``p + fraction * (envelope - p)``. Loading is exact, unloading lags.
    Typical fraction 0.05-0.2 (0..0.8), tau 0.2-2 s (0.02..30).
    """

    fraction: float = Field(0.1, ge=0.0, le=0.8)
    tau_s: float = Field(0.5, gt=0.0, le=30.0)


class CreepParams(EffectParams):
    """Slow rise of the reading under a constant load (viscoelastic creep).

    A first-order memory ``q`` of the pressure with time constant ``tau_s``;
    the reading is ``p + fraction * min(p, q)``: after a long constant load it
    reads ``(1 + fraction) p``, and it forgets when unloaded. Typical
    fraction 0.03-0.15 (0..0.5), tau 10-60 s (0.5..3600).
    """

    fraction: float = Field(0.06, ge=0.0, le=0.5)
    tau_s: float = Field(20.0, gt=0.0, le=3600.0)


class Hysteresis:
    domain = "kpa"

    def __init__(self, params: HysteresisParams, rate_hz: float) -> None:
        self.fraction = np.float32(params.fraction)
        self.keep = np.float32(np.exp(-1.0 / (rate_hz * params.tau_s)))
        self.envelope: np.ndarray | None = None

    def apply(self, x: np.ndarray) -> np.ndarray:
        count_call("hysteresis")
        env = np.zeros_like(x[0]) if self.envelope is None else self.envelope
        out = np.empty_like(x)
        for i in range(len(x)):
            p = x[i]
            env = np.maximum(p, p + (env - p) * self.keep)
            out[i] = p + self.fraction * (env - p)
        self.envelope = env
        return out


class Creep:
    domain = "kpa"

    def __init__(self, params: CreepParams, rate_hz: float) -> None:
        self.fraction = np.float32(params.fraction)
        self.alpha = np.float32(1.0 - np.exp(-1.0 / (rate_hz * params.tau_s)))
        self.memory: np.ndarray | None = None

    def apply(self, x: np.ndarray) -> np.ndarray:
        count_call("creep")
        q = np.zeros_like(x[0]) if self.memory is None else self.memory
        out = np.empty_like(x)
        for i in range(len(x)):
            p = x[i]
            q = q + (p - q) * self.alpha
            out[i] = p + self.fraction * np.minimum(p, q)
        self.memory = q
        return out
