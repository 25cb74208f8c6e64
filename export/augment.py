"""Training-time changes of the pressure maps that should not change what the model says.

Shift: an insole slides a little in the shoe and people differ in foot size,
so a pattern that moved by a taxel or two should still read the same. Each
foot is shifted on its own (rows and columns), and one shift holds for every
frame of a window: within 2.5 s the insole does not move in the shoe.

Crosstalk: a passive row-column array ghosts part of each row's and column's
load onto every taxel on it (the simulator's ``crosstalk`` effect), and how
much differs from insole to insole. A corpus renders one draw per subject, so
each person's pressure pattern comes with one amount of ghosting, and a model
can take the two together: a held-out subject's standing read as squat with
the crosstalk of its insole and as standing without it, although training
subjects had as much or more (docs/evaluation.md, the effect ablation).
Adding a fresh amount per chunk and foot shows each person on many insoles.
"""

from __future__ import annotations

import numpy as np
from scotti.models.contract import MAX_COUNT
from scotti.models.insole import insole_mask


def draw_shifts(rng: np.random.Generator, max_shift: int) -> np.ndarray:
    """(2, 2) int: (row, column) shift for the left and the right foot."""
    if max_shift <= 0:
        return np.zeros((2, 2), dtype=np.int64)
    return rng.integers(-max_shift, max_shift + 1, size=(2, 2))


def shift_feet(frames: np.ndarray, shifts: np.ndarray, cols: int) -> np.ndarray:
    """Shift each foot of (L, H, 2W) frames by its (rows, cols); vacated taxels read 0.

    Taxels pushed past the insole's edge are lost, never wrapped round to the
    other side or into the other foot.
    """
    out = np.zeros_like(frames)
    rows = frames.shape[1]
    for foot in (0, 1):
        dr, dc = (int(v) for v in shifts[foot])
        c0 = foot * cols
        src = frames[:, :, c0 : c0 + cols]
        dst = out[:, :, c0 : c0 + cols]
        r_to, r_from = _span(dr, rows)
        c_to, c_from = _span(dc, cols)
        dst[:, r_to, c_to] = src[:, r_from, c_from]
    return out


def _span(shift: int, size: int) -> tuple[slice, slice]:
    """Destination and source slices for a shift by ``shift`` along an axis of ``size``."""
    shift = max(-size, min(size, shift))
    if shift >= 0:
        return slice(shift, size), slice(0, size - shift)
    return slice(0, size + shift), slice(-shift, size)


def draw_crosstalk(rng: np.random.Generator, max_fraction: float) -> np.ndarray:
    """(2,) float32: the crosstalk added to the left and the right foot.

    Off (0), it draws nothing from ``rng``, so the rest of an epoch's plan is
    that of a run without this augmentation.
    """
    if max_fraction <= 0.0:
        return np.zeros(2, dtype=np.float32)
    return rng.uniform(0.0, max_fraction, size=2).astype(np.float32)


def add_crosstalk(frames: np.ndarray, fractions: np.ndarray, cols: int) -> np.ndarray:
    """Each foot of (L, H, 2W) float frames plus ``fraction * (row mean + column mean)``.

    As the simulator's effect: means over the whole foot grid, the ghost only on
    taxels (inside the insole outline), and the sum clipped where the ADC rails.
    """
    out = frames.astype(np.float32, copy=True)
    mask = _taxels(frames.shape[1], cols)
    for foot in (0, 1):
        if fractions[foot] <= 0.0:
            continue
        c0 = foot * cols
        x = out[:, :, c0 : c0 + cols]
        ghost = x.mean(axis=2, keepdims=True) + x.mean(axis=1, keepdims=True)
        out[:, :, c0 : c0 + cols] = np.minimum(x + fractions[foot] * ghost * mask, MAX_COUNT)
    return out


def _taxels(rows: int, cols: int) -> np.ndarray:
    """The insole outline for the contract's grid; any other grid (test data) is all taxels."""
    mask = insole_mask()
    if mask.shape != (rows, cols):
        return np.ones((rows, cols), dtype=np.float32)
    return mask.astype(np.float32)
