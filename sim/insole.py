"""The insole as a sensor: activation threshold, transfer curve, gain spread, saturation.

Every scene names its insole in an ``[insole]`` table::

    [insole]
    model = "realistic"     # or "ideal"
    threshold_kpa = 20      # any parameter left out takes the model's value

``realistic`` is a piezoresistive (FSR / velostat) array read through a
voltage divider per taxel:

- activation: the film's contact resistance stays open-circuit until the
  layers are pressed together; below ``threshold_kpa`` a taxel reads 0
  (the FSR "break force" of the Interlink FSR Integration Guide; Hollinger
  and Wanderley 2006 compare commercial FSRs); a fraction of a newton over
  a 4 x 8 mm taxel is some 5-30 kPa;
- transfer: the film's conductance grows as a power of the pressure,
  ``G ~ q^n``, ``n`` about 1 for commercial FSRs and below 1 for velostat
  and printed films (Giovanelli and Farella 2016, J Sensors, review FSR
  technology for wearable pressure sensing), and a divider turns a
  conductance into a voltage
  ``G / (G + G_ref)``. Together the rational curve
  ``counts = 4095 * q^n / (q^n + p_half^n)``, ``q = p - threshold``:
  steep at first, compressing towards full scale; ``p_half_kpa`` is where
  it reads half scale;
- saturation: the amplifier rails before the ADC's full scale: counts are
  clipped at ``saturation_counts``;
- gain spread: each taxel's sensitivity differs by a lognormal factor
  (mean 1, ``gain_sigma``), drawn once per insole (per session and foot).

``ideal`` is the test instrument: linear-ish divider (n = 1), a tiny
threshold, no spread, no saturation before 4095.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Final, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scotti.models import insole as models_insole
from scotti.models.contract import FRAME_COLS, FRAME_ROWS, MAX_COUNT

InsoleName = Literal["realistic", "ideal"]
_NOMINAL: Final = models_insole.DEFAULT_TRANSFER


@dataclass(frozen=True)
class Insole:
    """One insole model with every parameter resolved."""

    model: InsoleName = "realistic"
    # The nominal curve is the contract's count scale (models/insole.py).
    threshold_kpa: float = _NOMINAL.threshold_kpa  # activation pressure, below it reads 0
    p_half_kpa: float = _NOMINAL.p_half_kpa  # pressure above threshold reading half scale
    exponent: float = _NOMINAL.exponent  # power of the film's conductance law
    saturation_counts: float = _NOMINAL.saturation_counts  # where the amplifier rails
    gain_sigma: float = 0.15  # lognormal taxel-to-taxel sensitivity spread

    def as_dict(self) -> dict[str, float | str]:
        return dict(asdict(self))

    def transfer(self) -> models_insole.Transfer:
        """The count curve (the contract's form, models/insole.py) with this insole's values."""
        return models_insole.Transfer(
            p_half_kpa=self.p_half_kpa,
            threshold_kpa=self.threshold_kpa,
            exponent=self.exponent,
            saturation_counts=self.saturation_counts,
        )


MODELS: Final[dict[str, Insole]] = {
    "realistic": Insole(),
    "ideal": Insole(
        model="ideal",
        threshold_kpa=0.5,
        p_half_kpa=250.0,
        exponent=1.0,
        saturation_counts=float(MAX_COUNT),
        gain_sigma=0.0,
    ),
}


class InsoleSpec(BaseModel):
    """The scene's ``[insole]`` table: a model and optional overrides of its parameters."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    model: InsoleName = "realistic"
    threshold_kpa: float | None = Field(default=None, ge=0.0, le=200.0)
    p_half_kpa: float | None = Field(default=None, gt=0.0, le=5000.0)
    exponent: float | None = Field(default=None, gt=0.1, le=4.0)
    saturation_counts: float | None = Field(default=None, gt=0.0, le=float(MAX_COUNT))
    gain_sigma: float | None = Field(default=None, ge=0.0, le=1.0)

    def resolved(self) -> Insole:
        base = asdict(MODELS[self.model])
        given = {k: v for k, v in self.model_dump().items() if v is not None}
        return Insole(**{**base, **given})


REALISTIC: Final = MODELS["realistic"]
IDEAL: Final = MODELS["ideal"]


InsoleSpread = Literal["typical", "wide"]


def draw_insole(rng: np.random.Generator, spread: InsoleSpread = "typical") -> Insole:
    """A realistic insole with parameters drawn over their typical or wide ranges (corpora).

    ``typical`` stays near the nominal curve (the corpora the shipped models were
    first trained on; kept so those corpora remake byte for byte). ``wide``
    covers the insoles a user may bring: a stiff film that wakes late
    (threshold up to 60 kPa), soft or hard transfer curves (half scale
    80-700 kPa, log-uniform, exponent 0.5-1.5), early saturation and taxel
    gains spread up to 0.5: the scene schema accepts more, but past these a
    film is not a plantar pressure sensor any more.
    """
    if spread == "wide":
        return Insole(
            threshold_kpa=round(float(rng.uniform(0.0, 60.0)), 2),
            p_half_kpa=round(float(np.exp(rng.uniform(np.log(80.0), np.log(700.0)))), 1),
            exponent=round(float(rng.uniform(0.5, 1.5)), 3),
            saturation_counts=round(float(rng.uniform(3000.0, float(MAX_COUNT)))),
            gain_sigma=round(float(rng.uniform(0.0, 0.5)), 3),
        )
    return Insole(
        threshold_kpa=round(float(rng.uniform(8.0, 35.0)), 2),
        p_half_kpa=round(float(rng.uniform(120.0, 300.0)), 1),
        exponent=round(float(rng.uniform(0.6, 1.0)), 3),
        saturation_counts=round(float(rng.uniform(3500.0, float(MAX_COUNT)))),
        gain_sigma=round(float(rng.uniform(0.08, 0.25)), 3),
    )


def counts_from_kpa(kpa: np.ndarray, insole: Insole = IDEAL) -> np.ndarray:
    """Float32 counts of pressures (same shape), without gain spread; round when packing."""
    return models_insole.counts_from_kpa(kpa, insole.transfer())


def to_uint16(counts: np.ndarray) -> np.ndarray:
    """Round float counts to the wire's unsigned 12-bit samples."""
    rounded: np.ndarray = np.rint(counts)
    np.clip(rounded, 0, MAX_COUNT, out=rounded)
    return rounded.astype(np.uint16)


class InsoleArray:
    """A pair of insoles of one model, with their own taxel gains (drawn from ``seed``)."""

    def __init__(self, insole: Insole, seed: int) -> None:
        self.insole = insole
        rng = np.random.default_rng(np.random.SeedSequence([seed, 0x1501E]))
        s = insole.gain_sigma
        shape = (2, FRAME_ROWS, FRAME_COLS)
        # Lognormal with mean 1: exp(N(-s^2/2, s)).
        self.gain = np.exp(rng.normal(-0.5 * s * s, s, shape)).astype(np.float32) if s > 0 else None

    def sensed_kpa(self, kpa: np.ndarray) -> np.ndarray:
        """(n, 2, 32, 22) pressure as each taxel feels it (its gain applied)."""
        return kpa if self.gain is None else np.asarray(kpa * self.gain)

    def counts(self, kpa: np.ndarray) -> np.ndarray:
        """Float32 counts of sensed pressures: threshold, transfer curve, saturation."""
        return counts_from_kpa(kpa, self.insole)
