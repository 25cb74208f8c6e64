"""Calibration windows drawn as the checkpoint's training drew them.

The ``unfamiliar`` score says how far a window is from what the model was
trained on (export/ood_calibration.py). A model trained with
``--sensor-transfer`` and ``--tempo-stretch`` learnt windows read through
foreign insoles and played slower or faster, while statistics fitted on the
corpus's windows as recorded call exactly those windows unfamiliar: runs/v28
read real walking on 92 % of the windows, and its flag withheld a quarter or
more of the real windows, correct walking included.

So the calibration can draw its windows the way the checkpoint's last training
run did (its ``options``: ``sensor_transfer``, ``tempo_stretch``,
``tempo_range``), on both sides: the training subjects' windows for the
statistics and the held-out subjects' for the threshold, so about 1 % of
held-out windows as training saw them are flagged. Training's foot shifts
(two taxels at most) and crosstalk (3 %) are left out: they move a window
far less than another insole or tempo does. The draws come from a generator
seeded with the run's seed and the side, so an export is repeatable.

It is not the default (``scotti export --calibrate-as-trained`` asks for it):
measured on people neither training nor calibration saw
(experiments/flag_operating_points.py, docs/ood.md), it moves the flag along
one trade rather than making it a better detector of wrong answers: fewer
right answers withheld, more wrong ones sent. On the real files v28 so
calibrated sent 2 % of the windows as confident wrong answers without a flag,
where as recorded it sent none.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Final

import numpy as np
from scotti.export.sensor_transfer import draw_transfer, render
from scotti.export.tempo import DEFAULT_RANGE, EXTRA_RANGE, draw_tempo
from scotti.export.windows import Chunk, WindowDataset


@dataclass(frozen=True)
class InputDraws:
    """The input augmentations the calibration windows are drawn with (all off: as recorded)."""

    sensor_transfer: float = 0.0  # share of windows read through a drawn foreign insole
    tempo_stretch: float = 0.0  # share of windows played at a drawn tempo
    tempo_range: tuple[float, float] = DEFAULT_RANGE
    seed: int = 0
    # After seed, so that positional construction keeps its meaning:
    tempo_extra: float = 0.0  # a further share at a tempo drawn from tempo_extra_range
    tempo_extra_range: tuple[float, float] = EXTRA_RANGE

    @classmethod
    def from_options(cls, options: Mapping[str, Any] | None) -> InputDraws:
        """The draws of a checkpoint's training ``options``; none where it names none."""
        if not isinstance(options, Mapping):
            return cls()
        low, high = options.get("tempo_range") or DEFAULT_RANGE
        extra_low, extra_high = options.get("tempo_extra_range") or EXTRA_RANGE
        return cls(
            sensor_transfer=float(options.get("sensor_transfer") or 0.0),
            tempo_stretch=float(options.get("tempo_stretch") or 0.0),
            tempo_range=(float(low), float(high)),
            seed=int(options.get("seed") or 0),
            tempo_extra=float(options.get("tempo_extra") or 0.0),
            tempo_extra_range=(float(extra_low), float(extra_high)),
        )

    @property
    def active(self) -> bool:
        return self.sensor_transfer > 0.0 or self.tempo_stretch > 0.0 or self.tempo_extra > 0.0

    def describe(self) -> dict[str, Any]:
        """For the card: what the calibration windows were drawn with."""
        if not self.active:
            return {"as_recorded": True}
        described: dict[str, Any] = {
            "as_recorded": False,
            "sensor_transfer": self.sensor_transfer,
            "tempo_stretch": self.tempo_stretch,
            "tempo_range": list(self.tempo_range),
            "seed": self.seed,
        }
        if self.tempo_extra > 0.0:  # named only where drawn: older cards stay as they were
            described["tempo_extra"] = self.tempo_extra
            described["tempo_extra_range"] = list(self.tempo_extra_range)
        return described

    def generator(self, side: int) -> np.random.Generator:
        """The draws of one side (0: training subjects, 1: held out), repeatable."""
        return np.random.default_rng([self.seed, 7919, side])


AS_RECORDED: Final = InputDraws()  # no draws: the windows as the sessions hold them


def drawn_window(
    data: WindowDataset, session: int, start: int, draws: InputDraws, rng: np.random.Generator
) -> tuple[np.ndarray, int]:
    """One window as training would draw it: (T, H, 2W) float32 counts, target action.

    The tempo and the sensor are drawn from ``rng`` as training draws them per
    chunk (a tempo the window's span cannot hold is dropped, as training drops it).
    """
    chunk = Chunk(session, start, 1, 1, data.window)
    sensor = draw_transfer(rng, draws.sensor_transfer)
    tempo = draw_tempo(
        rng, draws.tempo_stretch, *draws.tempo_range, draws.tempo_extra, draws.tempo_extra_range
    )
    if not data.fits_tempo(chunk, tempo):
        tempo = 1.0
    frames = data.frames(chunk, tempo).astype(np.float32)
    if sensor is not None:
        frames = render(frames, sensor)
    return frames, int(data.targets(chunk, tempo).action[0])
