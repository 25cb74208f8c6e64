"""Playback rate of a replay or an emulated board: 1 = as recorded, N times faster, or max."""

from __future__ import annotations

import contextlib
import math
from typing import Literal, TypeAlias

Speed: TypeAlias = float | Literal["max"]


def parse_speed(value: object) -> Speed:
    """``"1"``, ``"4"``, ``0.5``, ``"max"`` (text or a number); ``ValueError`` otherwise."""
    if isinstance(value, str) and value.strip().lower() == "max":
        return "max"
    speed = math.nan
    if isinstance(value, str | int | float):
        with contextlib.suppress(ValueError):  # "fast": not a number, refused below
            speed = float(value)
    if not 0 < speed < math.inf:
        msg = f"speed must be a positive number or 'max', got {value!r}"
        raise ValueError(msg)
    return speed
