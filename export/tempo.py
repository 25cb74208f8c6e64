"""Tempo augmentation: a chunk of training windows played slower or faster.

Real walks read by the model hang on their tempo: gaitpdb's walks played at
0.8 and 0.65 of their speed (experiments/real_tempo.py) lose much of their
`walking` reading, while the simulated population steps 95-135 times a minute.
Playing a chunk at tempo ``tau`` reads the session at slots ``start + tau * j``
(frame j of the chunk), so ``tau`` < 1 is slower (each second of the session
lasts ``1/tau`` s), ``tau`` > 1 faster. Between slots the frames are read as a
straight line (the insole samples a continuous pressure 16 times a second);
keypoints likewise; an action and a progress are the nearest slot's (progress
wraps from 1 to 0 between reps, so it is not interpolated). The labels stay
true: a squat played slower is a slower squat at the same fraction of its rep.

Not for jumps: flight lasts what gravity allows, so a chunk whose slots hold
a jump anywhere is played as it is. Nor across what a window may not span
(export/windows.py's rules): a tempo whose slots leave the segment, meet a
zero-filled foot or an unlabelled target is dropped for that chunk (tempo 1).
"""

from __future__ import annotations

import math
from typing import Final

import numpy as np
from scotti.export.data import SessionArrays
from scotti.models import contract

# Log-uniform draw between these tempi unless asked otherwise (`scotti train --tempo-range`):
# from gaitpdb's slowest walk at 0.65 of the population's slowest (79 -> 55 steps a minute,
# the simulator's floor) to 1.3 x.
DEFAULT_RANGE: Final = (0.65, 1.3)
# A second share beside it (`scotti train --tempo-extra`), drawn over the scene schema's whole
# script.tempo range unless asked otherwise: one wide range alone cost the real walks
# (runs/v41, docs/generalisation.md), so the near range can keep its share while the
# extremes are added.
EXTRA_RANGE: Final = (0.3, 3.0)
NOT_STRETCHED: Final = frozenset({contract.ACTIONS.index("jump")})


def draw_tempo(
    rng: np.random.Generator,
    share: float,
    low: float,
    high: float,
    extra_share: float = 0.0,
    extra_range: tuple[float, float] = EXTRA_RANGE,
) -> float:
    """With probability ``share``, a tempo log-uniform in [low, high]; with probability
    ``extra_share`` beside it, one log-uniform in ``extra_range``; else 1.

    Off (both shares 0) it draws nothing from ``rng``, so an epoch's plan stays that
    of a run without this augmentation; without an extra share it draws exactly as
    it did before the extra share existed (one number, then the tempo if stretched).
    """
    if share <= 0.0 and extra_share <= 0.0:
        return 1.0
    u = rng.random()
    if u < share:
        lo, hi = low, high
    elif u < share + extra_share:
        lo, hi = extra_range
    else:
        return 1.0
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def positions(
    start: int, frame_count: int, window: int, stride: int, count: int, tempo: float
) -> tuple[np.ndarray, np.ndarray]:
    """Slots (fractional) the chunk's frames and its windows' targets are read at."""
    frames = start + tempo * np.arange(frame_count, dtype=np.float64)
    targets = start + tempo * (window + stride * np.arange(count, dtype=np.float64))
    return frames, targets


def fits(s: SessionArrays, frame_pos: np.ndarray, target_pos: np.ndarray) -> bool:
    """The session holds every slot these positions read, as a window may use them."""
    first = math.floor(float(frame_pos[0]))
    last = math.ceil(float(max(frame_pos[-1], target_pos[-1])))
    if first < 0 or last >= len(s):
        return False
    span = slice(first, last + 1)
    if np.any(s.segment[span] != s.segment[first]) or not np.all(s.frame_ok[span]):
        return False
    if np.isin(s.action[span], list(NOT_STRETCHED)).any():
        return False
    below, above = np.floor(target_pos).astype(np.int64), np.ceil(target_pos).astype(np.int64)
    return bool(s.has_label[below].all() and s.has_label[above].all())


def read_between(values: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """``values`` (N, ...) read at fractional slots ``pos`` on straight lines, float32."""
    below = np.minimum(np.floor(pos).astype(np.int64), len(values) - 1)
    above = np.minimum(below + 1, len(values) - 1)
    w = (pos - below).astype(np.float32).reshape((-1,) + (1,) * (values.ndim - 1))
    lo = values[below].astype(np.float32)
    return np.asarray(lo + w * (values[above].astype(np.float32) - lo), dtype=np.float32)


def nearest(values: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """``values`` at the slot nearest each position."""
    picked: np.ndarray = values[np.minimum(np.rint(pos).astype(np.int64), len(values) - 1)]
    return picked
