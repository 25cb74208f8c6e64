"""Random shift of the pressure maps: the same foot lands a few taxels off from step to step.

An insole slides a little in the shoe and people differ in foot size, so a
pattern that moved by a taxel or two should still read the same. Each foot
is shifted on its own (rows and columns), and one shift holds for every
frame of a window: within 2.5 s the insole does not move in the shoe.
"""

from __future__ import annotations

import numpy as np


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
