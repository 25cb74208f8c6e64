"""Smooth curves the recipes are drawn with: keyframes, bumps, soft minimum.

Every curve here is C1: keyframes are joined by cubic Hermite pieces, so a
recipe that gives zero velocity at its first and last keyframe joins the
next one without a kink.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

Array = npt.NDArray[np.float64]


def hermite(
    t: npt.ArrayLike,
    knot_t: npt.ArrayLike,
    knot_y: npt.ArrayLike,
    knot_v: npt.ArrayLike | None = None,
) -> Array:
    """Cubic Hermite through keyframes (K,) -> values (K, ...) with velocities.

    Velocities default to zero (eases in and out of every keyframe). Before
    the first and after the last keyframe the end value holds.
    """
    tq = np.asarray(t, dtype=np.float64)
    kt = np.asarray(knot_t, dtype=np.float64)
    ky = np.asarray(knot_y, dtype=np.float64)
    kv = np.zeros_like(ky) if knot_v is None else np.asarray(knot_v, dtype=np.float64)
    if kt.size == 1:
        return np.broadcast_to(ky[0], (*tq.shape, *ky.shape[1:])).copy()
    tc = np.clip(tq, kt[0], kt[-1])
    i = np.clip(np.searchsorted(kt, tc, side="right") - 1, 0, kt.size - 2)
    dt = kt[i + 1] - kt[i]
    s = (tc - kt[i]) / dt
    extra = (1,) * (ky.ndim - 1)
    s = s.reshape(*s.shape, *extra)
    dt = dt.reshape(*dt.shape, *extra)
    h00 = 2 * s**3 - 3 * s**2 + 1
    h10 = s**3 - 2 * s**2 + s
    h01 = -2 * s**3 + 3 * s**2
    h11 = s**3 - s**2
    return np.asarray(
        h00 * ky[i] + h10 * dt * kv[i] + h01 * ky[i + 1] + h11 * dt * kv[i + 1], dtype=np.float64
    )


def ease(s: npt.ArrayLike) -> Array:
    """0 -> 1 with zero slope at both ends (cosine), clipped outside [0, 1]."""
    x = np.clip(np.asarray(s, dtype=np.float64), 0.0, 1.0)
    return np.asarray(0.5 - 0.5 * np.cos(np.pi * x), dtype=np.float64)


def bump(s: npt.ArrayLike) -> Array:
    """0 -> 1 -> 0 over [0, 1] with zero slope at the ends; 0 outside."""
    x = np.clip(np.asarray(s, dtype=np.float64), 0.0, 1.0)
    return np.asarray(np.sin(np.pi * x) ** 2, dtype=np.float64)


def soft_min(values: list[Array], softness: float) -> Array:
    """Smooth minimum (never above the true minimum) of equally shaped arrays."""
    stack = np.stack(values)
    low = stack.min(axis=0)
    return np.asarray(
        low - softness * np.log(np.sum(np.exp(-(stack - low) / softness), axis=0)),
        dtype=np.float64,
    )


def box_smooth(x: Array, width: int, passes: int = 2) -> Array:
    """Moving average along axis 0 (edges repeated); two passes give a C1-like curve."""
    if width <= 1:
        return x
    out = np.asarray(x, dtype=np.float64)
    half = width // 2
    kernel = np.full(width, 1.0 / width)
    for _ in range(passes):
        padded = np.concatenate(
            [np.repeat(out[:1], half, axis=0), out, np.repeat(out[-1:], width - 1 - half, axis=0)]
        )
        flat = padded.reshape(len(padded), -1)
        smoothed = np.stack(
            [np.convolve(flat[:, j], kernel, mode="valid") for j in range(flat.shape[1])], axis=1
        )
        out = smoothed.reshape(len(out), *out.shape[1:])
    return out
