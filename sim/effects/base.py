"""What every effect shares: strict parameter models, call counting, RNG streams.

Each effect is applied only when a scene names it. Its random numbers come
from its own stream, derived from the scene seed, its name and its position
in the scene's list, so naming one more effect never changes another's.
"""

from __future__ import annotations

import zlib
from collections import Counter
from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict

# How often each effect's function ran in this process. Tests read it to
# prove that an effect nobody named cost nothing.
EFFECT_CALLS: Counter[str] = Counter()


class EffectParams(BaseModel):
    """Base of every effect's parameters: unknown keys are mistakes."""

    model_config = ConfigDict(extra="forbid", frozen=True)


@dataclass(frozen=True)
class Effect:
    """One named effect with validated parameters; ``index``: its place in the scene."""

    name: str
    params: EffectParams
    index: int = 0

    def rng(self, seed: int) -> np.random.Generator:
        key = zlib.crc32(self.name.encode())
        return np.random.default_rng(np.random.SeedSequence([seed, self.index, key]))

    def as_dict(self) -> dict[str, object]:
        return {"name": self.name, **self.params.model_dump()}


def count_call(name: str) -> None:
    EFFECT_CALLS[name] += 1
