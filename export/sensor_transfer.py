"""Our pressure maps as `scotti import` would bring them in from another insole.

The shipped model learnt one insole: 32 x 22 taxels per foot, 16 Hz, the
contract's count curve (models/insole.py). Recordings of other insoles reach
it through ``importers/``: resampled in time onto 16 Hz
(``importers.timebase.box_average``), remapped in space onto our grid by
area (``importers.grid``), then put on our count scale through our curve.
What comes out differs from our own insole's maps in four ways, and a model
that never saw them reads a softer insole's squat as standing:

- space: a coarser or finer grid, or a few discrete cells (8, 16, 99 per
  foot), averages pressure over its own cells; the import spreads each cell
  back over the taxels under it;
- the film: its own activation threshold, transfer curve and saturation, and
  a spread of sensitivity from cell to cell;
- scale: a gain nobody knows exactly (a vendor's calibration, the body mass
  a recording was scaled by), from 0.5 to 2 times ours;
- time: another rate (8-100 Hz), box-averaged onto our 16 Hz.

``render`` takes counts back to pressure (``kpa_from_counts`` of
models/input_checks.py, the inverse of our curve: 0 stays 0, a taxel at our
rail stays at the rail's pressure), lets a ``ForeignSensor`` read that
pressure (its cells' area means, its gains, its own curve, in its own count
scale), takes the reading as our importer does (through the inverse of our
curve, the ``per_kpa`` route: a reading is taken for the pressure our
insole would report it as), resamples it in time and space as the importer
does, and puts it on our counts through our curve, rounded as an imported
session file holds them. Resampling in time and remapping in space are both
linear, so they commute: the time step runs on whichever of the two grids
is smaller. The sensor's curve acts on its 16 Hz readings, before the time
step; the importer sees readings taken at the source's rate, so fast
transitions of a slow sensor are a little smoother here than in a real
import.

A sensor with our grid, our curve, gain 1, no cell spread and our rate is
the identity (up to the rail: an import never gives more than our curve's
saturation). ``draw_sensor`` draws foreign ones for training
(``--sensor-transfer P``: the share of chunks rendered through one);
experiments/insole_transfer.py renders whole sessions through named ones.
Where a sensor senses (its grid or discrete cells) is ``sensor_geometry``'s.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field, replace
from typing import Any, Final

import numpy as np
from scotti.export.sensor_geometry import CellGeometry as CellGeometry
from scotti.export.sensor_geometry import Geometry as Geometry
from scotti.export.sensor_geometry import GridGeometry as GridGeometry
from scotti.export.sensor_geometry import cell_layouts, geometry_of
from scotti.export.sensor_geometry import one_thread_product as one_thread_product
from scotti.importers.timebase import box_average
from scotti.models.contract import FRAME_COLS, FRAME_RATE_HZ, FRAME_ROWS, MAX_COUNT
from scotti.models.input_checks import kpa_from_counts
from scotti.models.insole import DEFAULT_TRANSFER, Transfer, counts_from_kpa

# What draw_sensor draws, and why so far:
# Insoles on the market and in public sets sample at 8-100 Hz; a dozen rates a quarter
# apart cover that, and keep the time matrices of a run few enough to cache.
RATES_HZ: Final = (8.0, 10.0, 12.5, 16.0, 20.0, 25.0, 32.0, 40.0, 50.0, 64.0, 80.0, 100.0)
THRESHOLD_KPA: Final = (5.0, 60.0)  # a film that wakes early, to one that wakes late
HALF_SCALE_KPA: Final = (100.0, 600.0)  # log-uniform: a soft film to a stiff one
EXPONENT: Final = (0.6, 1.4)  # printed films and velostat (< 1) to FSRs (about 1) and above
SATURATION_COUNTS: Final = (3000.0, float(MAX_COUNT))  # where its amplifier rails
GAIN: Final = (0.5, 2.0)  # log-uniform: what an import's scale may be off by
FOOT_GAIN_SIGMA: Final = 0.1  # the two feet's gains differ by this (lognormal)
CELL_SIGMA: Final = (0.0, 0.3)  # cell-to-cell sensitivity spread (lognormal)
GRID_ROWS: Final = (8, 64)  # along the foot, log-uniform
GRID_COLS: Final = (4, 32)  # across, log-uniform, never more than the rows
CELL_SHARE: Final = 0.5  # of the drawn sensors that have discrete cells (when layouts exist)
PHASES: Final = 4  # the sensor's first sample, in quarters of its period after our frame 0

_MAX_CACHED_OPERATORS: Final = 512


# --- our count curve, both ways ------------------------------------------------


@functools.lru_cache(maxsize=1)
def _kpa_of_each_count() -> np.ndarray:
    """(4096,) float32: ``kpa_from_counts`` of every whole count, our curve."""
    return kpa_from_counts(np.arange(MAX_COUNT + 1)).astype(np.float32)


def kpa_from_whole_counts(counts: np.ndarray) -> np.ndarray:
    """``kpa_from_counts`` (our curve) of counts as the wire carries them, by table.

    Fractions are rounded to the nearest count first: a sensor resolves no finer.
    """
    index = np.clip(np.rint(counts), 0, MAX_COUNT).astype(np.intp)
    return np.asarray(_kpa_of_each_count()[index])


def read_as_ours(kpa: np.ndarray, transfer: Transfer) -> np.ndarray:
    """What our importer takes a pressure read through ``transfer`` for, in kPa.

    ``kpa_from_counts(counts_from_kpa(kpa, transfer))``, in one power: the
    sensor's counts ``4095 r / (1 + r)`` with ``r = ((p - t) / h)^n`` go back
    through our curve as ``t0 + h0 r^(1/n0)``, ``r`` capped where the
    sensor's rail, or ours, is reached.
    """
    f32 = np.float32
    ours = DEFAULT_TRANSFER
    q = np.asarray(kpa, dtype=f32) - f32(transfer.threshold_kpa)
    pressed = q > 0.0
    out = np.zeros(q.shape, f32)
    v = q[pressed] / f32(transfer.p_half_kpa)
    v **= f32(transfer.exponent / ours.exponent)
    rail = min(transfer.saturation_counts, ours.saturation_counts, MAX_COUNT - 1.0)
    np.minimum(v, f32((rail / (MAX_COUNT - rail)) ** (1.0 / ours.exponent)), out=v)
    v *= f32(ours.p_half_kpa)
    v += f32(ours.threshold_kpa)
    out[pressed] = v
    return out


# --- the sensor ---------------------------------------------------------------


@dataclass(frozen=True)
class ForeignSensor:
    """Another insole: where it senses, how it reads pressure, how fast.

    The defaults are our own insole: ``render`` through it changes nothing.
    """

    layout: str | None = None  # discrete cells (importers.layouts name); None: a grid
    rows: int = FRAME_ROWS  # the grid, in our orientation (ignored for cells)
    cols: int = FRAME_COLS
    rate_hz: float = FRAME_RATE_HZ
    phase: float = 0.0  # its first sample, as a share of its period after our frame 0
    transfer: Transfer = DEFAULT_TRANSFER  # its curve, onto its own 12-bit scale
    gain: tuple[float, float] = (1.0, 1.0)  # left, right: its sensitivity against ours
    cell_sigma: float = 0.0  # lognormal spread of its cells' sensitivity
    seed: int = 0  # of the cells' sensitivities

    @property
    def native_geometry(self) -> bool:
        return self.layout is None and (self.rows, self.cols) == (FRAME_ROWS, FRAME_COLS)

    @property
    def native_rate(self) -> bool:
        return self.rate_hz == FRAME_RATE_HZ and self.phase == 0.0

    @property
    def native(self) -> bool:
        """Our insole: ``render`` returns the counts it was given (below the rail)."""
        return (
            self.native_geometry
            and self.native_rate
            and self.transfer == DEFAULT_TRANSFER
            and self.gain == (1.0, 1.0)
            and self.cell_sigma == 0.0
        )

    def describe(self) -> str:
        """One line for logs and tables: geometry, rate, curve, gains."""
        where = f"{self.layout} cells" if self.layout else f"grid {self.rows}x{self.cols}"
        t = self.transfer
        return (
            f"{where}, {self.rate_hz:g} Hz, threshold {t.threshold_kpa:.0f} kPa, half scale "
            f"{t.p_half_kpa:.0f} kPa, power {t.exponent:.2f}, rail {t.saturation_counts:.0f}, "
            f"gain {self.gain[0]:.2f}/{self.gain[1]:.2f}, cell spread {self.cell_sigma:.2f}"
        )

    def as_dict(self) -> dict[str, Any]:
        return {
            "layout": self.layout,
            "rows": self.rows,
            "cols": self.cols,
            "rate_hz": self.rate_hz,
            "phase": self.phase,
            "transfer": {
                "threshold_kpa": self.transfer.threshold_kpa,
                "p_half_kpa": self.transfer.p_half_kpa,
                "exponent": self.transfer.exponent,
                "saturation_counts": self.transfer.saturation_counts,
            },
            "gain": list(self.gain),
            "cell_sigma": self.cell_sigma,
            "seed": self.seed,
        }


OURS: Final = ForeignSensor()


def with_curve(sensor: ForeignSensor, **curve: float) -> ForeignSensor:
    """``sensor`` with some of its curve's parameters changed (named as in ``Transfer``)."""
    return replace(sensor, transfer=replace(sensor.transfer, **curve))


# --- time: its rate -> our 16 Hz -----------------------------------------------


def resample_in_time(values: np.ndarray, rate_hz: float, phase: float) -> np.ndarray:
    """(L, D) at 16 Hz, sampled by a sensor at ``rate_hz`` and box-averaged back onto 16 Hz.

    The sensor samples the signal between our frames as a straight line
    (held beyond the ends) every 1/rate s, starting ``phase`` periods after
    frame 0; the samples go back onto our frames' times as the importer takes
    them (``importers.timebase.box_average``). Works through the output a
    block at a time, so a whole session fits in memory.
    """
    frames = values.shape[0]
    out = np.empty(values.shape, dtype=np.float32)
    period = 1.0 / rate_hz
    t_out = np.arange(frames) / FRAME_RATE_HZ
    margin = 0.5 / FRAME_RATE_HZ + 2.0 * period  # every box lies within the samples taken
    first = phase * period - math.ceil(margin / period) * period  # sample k at first + k/rate
    block = 512
    for a in range(0, frames, block):
        b = min(a + block, frames)
        k0 = math.floor((t_out[a] - margin - first) / period)
        k1 = math.ceil((t_out[b - 1] + margin - first) / period)
        s = first + period * np.arange(max(k0, 0), k1 + 1)
        out[a:b] = box_average(s, _between_frames(values, s), t_out[a:b])
    return out


def _between_frames(values: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(len(t), D) the 16 Hz frames as a piecewise-linear signal at times ``t`` (s)."""
    frames = values.shape[0]
    x = np.clip(t * FRAME_RATE_HZ, 0.0, frames - 1.0)
    i = np.minimum(np.floor(x).astype(np.int64), max(frames - 2, 0))
    w = (x - i)[:, None]
    if frames == 1:
        return np.repeat(np.asarray(values[:1], dtype=np.float64), t.size, axis=0)
    return np.asarray((1.0 - w) * values[i] + w * values[i + 1])


@dataclass(frozen=True)
class BandedOperator:
    """A (frames, frames) matrix that is 0 beyond a few diagonals, kept as those diagonals.

    ``apply`` multiplies by it with a few elementwise passes: no BLAS call,
    whose threads would fight the training step's for the cores.
    """

    offsets: tuple[int, ...]  # column - row of each kept diagonal
    diagonals: np.ndarray  # (len(offsets), frames) float32: [k, i] = M[i, i + offsets[k]]

    @classmethod
    def of(cls, matrix: np.ndarray) -> BandedOperator:
        frames = matrix.shape[0]
        rows, columns = np.nonzero(np.abs(matrix) > 1e-7)
        offsets = tuple(range(int((columns - rows).min()), int((columns - rows).max()) + 1))
        diagonals = np.zeros((len(offsets), frames), dtype=np.float32)
        for k, d in enumerate(offsets):
            i = np.arange(max(0, -d), min(frames, frames - d))
            diagonals[k, i] = matrix[i, i + d]
        return cls(offsets, diagonals)

    def apply(self, x: np.ndarray) -> np.ndarray:
        """M @ x for x (frames, D)."""
        frames = x.shape[0]
        out = np.zeros(x.shape, dtype=np.float32)
        for k, d in enumerate(self.offsets):
            rows = slice(max(0, -d), min(frames, frames - d))
            cols = slice(rows.start + d, rows.stop + d)
            out[rows] += self.diagonals[k, rows, None] * x[cols]
        return out


@functools.lru_cache(maxsize=_MAX_CACHED_OPERATORS)
def time_operator(frames: int, rate_hz: float, phase: float) -> BandedOperator:
    """The matrix M with ``resample_in_time(x) == M @ x`` for ``frames`` frames.

    A training chunk is short: one banded product instead of sampling its
    hundreds of taxels; the same few (length, rate, phase) come back every
    chunk (8 lengths at most, 12 rates, 4 phases), so the operators are cached.
    """
    return BandedOperator.of(resample_in_time(np.eye(frames, dtype=np.float32), rate_hz, phase))


# --- the whole way ------------------------------------------------------------


def render(counts: np.ndarray, sensor: ForeignSensor, *, whole: bool = False) -> np.ndarray:
    """(L, 32, 2 x 22) counts, left foot columns first -> float32 counts through ``sensor``.

    Rounded to whole counts in [0, 4095], as an imported session holds them.
    ``whole``: a whole session (time resampled block by block) rather than a
    training chunk (one cached time matrix).
    """
    frames, rows, both = counts.shape
    cols = both // 2
    if (rows, cols) != (FRAME_ROWS, FRAME_COLS):
        msg = f"sensor transfer needs {FRAME_ROWS} x {FRAME_COLS} feet, got {rows} x {cols}"
        raise ValueError(msg)
    kpa = kpa_from_whole_counts(counts).reshape(frames, rows, 2, cols).transpose(0, 2, 1, 3)
    # (L, 2, 32, 22) kPa: each foot on our grid
    feet = None if sensor.native_geometry else geometry_of(sensor.layout, sensor.rows, sensor.cols)
    if feet is None:
        cells = kpa.reshape(frames, 2, -1)
    else:
        cells = np.stack([feet[k].down(kpa[:, k]) for k in range(2)], axis=1)  # (L, 2, n)
    cells = cells * sensitivity(sensor, cells.shape[2])  # what its cells feel
    # Its own counts, and the pressure our importer takes them for:
    apparent = read_as_ours(cells, sensor.transfer)
    resample = not sensor.native_rate
    if resample and apparent.shape[2] <= rows * cols:
        apparent = _in_time(apparent, sensor, whole=whole)
        resample = False
    grid = (
        apparent.reshape(frames, 2, rows, cols)
        if feet is None
        else np.stack([feet[k].up(apparent[:, k]) for k in range(2)], axis=1)
    )
    if resample:
        grid = _in_time(grid, sensor, whole=whole)
    out = counts_from_kpa(grid)  # onto our count scale, as the importer does last
    np.rint(out, out=out)
    np.clip(out, 0.0, float(MAX_COUNT), out=out)
    return np.ascontiguousarray(out.transpose(0, 2, 1, 3).reshape(frames, rows, both))


def _in_time(x: np.ndarray, sensor: ForeignSensor, *, whole: bool) -> np.ndarray:
    flat = x.reshape(x.shape[0], -1)
    if whole:
        done = resample_in_time(flat, sensor.rate_hz, sensor.phase)
    else:
        done = time_operator(x.shape[0], sensor.rate_hz, sensor.phase).apply(flat)
    return np.asarray(done.reshape(x.shape), dtype=np.float32)


def sensitivity(sensor: ForeignSensor, cells: int) -> np.ndarray:
    """(2, cells) float32: each foot's gain times each cell's own sensitivity (mean 1)."""
    gain = np.asarray(sensor.gain, dtype=np.float32)[:, None]
    s = sensor.cell_sigma
    if s <= 0.0:
        return np.broadcast_to(gain, (2, cells))
    rng = np.random.default_rng([sensor.seed, 0x5E45])
    spread = np.exp(rng.normal(-0.5 * s * s, s, (2, cells))).astype(np.float32)
    return np.asarray(gain * spread)


# --- drawing sensors for training ----------------------------------------------


@dataclass(frozen=True)
class SensorDraw:
    """What ``draw_sensor`` may draw (the ranges above, the layouts there are)."""

    layouts: tuple[str, ...] = field(default_factory=cell_layouts)


def draw_sensor(rng: np.random.Generator, draw: SensorDraw | None = None) -> ForeignSensor:
    """A foreign insole: geometry, rate, curve, gains, each over the ranges above."""
    layouts = (draw or SensorDraw()).layouts
    if layouts and rng.random() < CELL_SHARE:
        layout: str | None = layouts[int(rng.integers(len(layouts)))]
        rows, cols = 0, 0
    else:
        layout = None
        rows = _log_int(rng, *GRID_ROWS)
        cols = min(rows, _log_int(rng, *GRID_COLS))
    rate = RATES_HZ[int(rng.integers(len(RATES_HZ)))]
    phase = int(rng.integers(PHASES)) / PHASES
    transfer = Transfer(
        threshold_kpa=round(float(rng.uniform(*THRESHOLD_KPA)), 1),
        p_half_kpa=round(_log_uniform(rng, *HALF_SCALE_KPA), 1),
        exponent=round(float(rng.uniform(*EXPONENT)), 3),
        saturation_counts=float(round(rng.uniform(*SATURATION_COUNTS))),
    )
    common = _log_uniform(rng, *GAIN)
    feet = np.exp(rng.normal(0.0, FOOT_GAIN_SIGMA, 2))
    return ForeignSensor(
        layout=layout,
        rows=rows,
        cols=cols,
        rate_hz=rate,
        phase=phase,
        transfer=transfer,
        gain=(round(common * float(feet[0]), 3), round(common * float(feet[1]), 3)),
        cell_sigma=round(float(rng.uniform(*CELL_SIGMA)), 3),
        seed=int(rng.integers(1 << 31)),
    )


def draw_transfer(
    rng: np.random.Generator, probability: float, draw: SensorDraw | None = None
) -> ForeignSensor | None:
    """With ``probability``, a drawn sensor; else None (our own insole).

    Off (0), it draws nothing from ``rng``: the rest of an epoch's plan is
    that of a run without this augmentation.
    """
    if probability <= 0.0:
        return None
    if rng.random() >= probability:
        return None
    return draw_sensor(rng, draw)


def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def _log_int(rng: np.random.Generator, lo: int, hi: int) -> int:
    return round(_log_uniform(rng, lo - 0.49, hi + 0.49))
