"""Counters that wrap: the board's u16 frame sequence and u32 microsecond clock.

The host never compares raw values with ``<``. It takes the signed, wrap-aware
difference, which is right as long as two values are less than half the
range apart (32768 frames = 34 min at 16 Hz; 2**31 us = 35.8 min).
"""

from __future__ import annotations

SEQ_BITS = 16  # frame sequence number width on the wire
CLOCK_BITS = 32  # board clock width on the wire (microseconds, wraps every ~71.6 min)


def wrap_delta(new: int, old: int, bits: int) -> int:
    """``new - old`` for ``bits``-wide wrapping counters, in [-2**(bits-1), 2**(bits-1))."""
    half = 1 << (bits - 1)
    return ((new - old + half) & ((1 << bits) - 1)) - half


def seq_delta(new: int, old: int) -> int:
    """Frames from ``old`` to ``new`` (positive when ``new`` is later), u16 wrap-aware."""
    return wrap_delta(new, old, SEQ_BITS)


def clock_delta_us(new: int, old: int) -> int:
    """Microseconds from ``old`` to ``new`` on the board clock, u32 wrap-aware."""
    return wrap_delta(new, old, CLOCK_BITS)


class Unwrapper:
    """Turns a wrapping counter into an unbounded int that keeps counting.

    The first value is returned as is; each next one moves by the wrap-aware
    difference from the previous value, so 65535 -> 0 continues as 65536.
    A step backwards stays a step backwards (the result can decrease).
    """

    def __init__(self, bits: int) -> None:
        self.bits = bits
        self._last_raw: int | None = None
        self._value = 0

    def __call__(self, raw: int) -> int:
        return self.unwrap(raw)

    def unwrap(self, raw: int) -> int:
        if self._last_raw is None:
            self._value = raw
        else:
            self._value += wrap_delta(raw, self._last_raw, self.bits)
        self._last_raw = raw
        return self._value

    def reset(self) -> None:
        self._last_raw = None
        self._value = 0
