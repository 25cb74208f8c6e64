"""Each foot's source values onto 16 Hz, our 32 x 22 grid and our counts: the import's one path.

Whatever the source (a grid from a table, a vendor's grid, a vendor's
discrete cells), an import holds, per foot it has, the source's values as
stored, flat, side by side in one (N, D) array, and a map from a foot's
values to our counts. The order is time, then space, then scale: the
values are averaged over each output frame's period first (box_average:
linear, so on the source's own values), then each foot's map takes them
onto our grid (linear: orientation and area-weighted remapping, or cells
rendered by their layout) and through our transfer curve (a curve, so
last, on our grid). A foot the source does not hold has no map: its
counts stay zero and the session gets no packets for it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np
from scotti.importers.timebase import Timeline, box_average
from scotti.models.contract import FRAME_COLS, FRAME_ROWS, MAX_COUNT

FEET: Final = ("left", "right")  # the order of axis 1 of every (N, 2, ...) array of an import
_CHUNK: Final = 256  # output frames taken from source values to counts at once

# A foot's (n, d) source values, averaged onto output frames -> (n, 32, 22) float32 counts,
# a new array (the caller rounds it in place).
FootMap = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True, eq=False)
class FeetSource:
    """Source values of the feet a recording holds, with each foot's map to our counts."""

    path: Path
    times: np.ndarray  # (N,) float64 seconds, strictly increasing
    values: np.ndarray  # (N, D) source values of every foot held, side by side
    columns: dict[str, slice]  # foot -> its columns of ``values``
    maps: dict[str, FootMap]  # foot -> its map; a foot not held is in neither

    @property
    def feet(self) -> tuple[str, ...]:
        """The feet held, left first."""
        return tuple(f for f in FEET if f in self.maps)

    @property
    def absent(self) -> tuple[str, ...]:
        return tuple(f for f in FEET if f not in self.maps)

    @property
    def rate_hz(self) -> float:
        span = float(self.times[-1] - self.times[0]) if self.times.size > 1 else 0.0
        return (self.times.size - 1) / span if span > 0 else 0.0


def resample_feet(source: FeetSource, timeline: Timeline) -> np.ndarray:
    """(M, 2, 32, 22) uint16 counts at the timeline's frames; zeros for a foot not held."""
    out = np.zeros((len(timeline), 2, FRAME_ROWS, FRAME_COLS), dtype=np.uint16)
    starts = np.searchsorted(timeline.segment, np.arange(len(timeline.source_ranges)))
    ends = np.r_[starts[1:], len(timeline)]
    for (a, b), first, stop in zip(timeline.source_ranges, starts, ends, strict=True):
        # A chunk at a time, from resampling to counts: the arrays stay in cache.
        for s in range(int(first), int(stop), _CHUNK):
            chunk = slice(s, min(s + _CHUNK, int(stop)))
            values = box_average(
                source.times[a : b + 1], source.values[a : b + 1], timeline.times[chunk]
            )
            for foot in source.feet:
                counts = source.maps[foot](values[:, source.columns[foot]])
                np.rint(counts, out=counts)
                np.clip(counts, 0, MAX_COUNT, out=counts)
                out[chunk, FEET.index(foot)] = counts
    return out
