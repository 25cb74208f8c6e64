"""Wrap-aware differences and unwrapping of the u16 sequence and u32 clock."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scotti.firmware_protocol.wrap import Unwrapper, clock_delta_us, seq_delta


@pytest.mark.parametrize(
    ("new", "old", "delta"),
    [(5, 3, 2), (3, 5, -2), (0, 65535, 1), (65535, 0, -1), (2, 65530, 8), (32767, 0, 32767)],
)
def test_seq_delta(new: int, old: int, delta: int) -> None:
    assert seq_delta(new, old) == delta


def test_seq_delta_half_range_is_negative() -> None:
    assert seq_delta(32768, 0) == -32768


def test_clock_delta_across_the_71_minute_wrap() -> None:
    assert clock_delta_us(10, 2**32 - 62_490) == 62_500
    assert clock_delta_us(2**32 - 62_490, 10) == -62_500
    assert round((2**32) / 1e6 / 60, 1) == 71.6


@settings(deadline=None)
@given(st.integers(0, 65535), st.integers(-32768, 32767))
def test_seq_delta_inverts_modular_addition(old: int, step: int) -> None:
    assert seq_delta((old + step) % 65536, old) == step


def test_unwrapper_keeps_counting_across_wraps() -> None:
    unwrap = Unwrapper(bits=16)
    raw = [65533, 65534, 65535, 0, 1, 3, 2]
    assert [unwrap(r) for r in raw] == [65533, 65534, 65535, 65536, 65537, 65539, 65538]
    unwrap.reset()
    assert unwrap(7) == 7


def test_unwrapper_of_the_board_clock_over_two_wraps() -> None:
    unwrap = Unwrapper(bits=32)
    step = 62_500 * 16 * 60  # one minute in microseconds
    values = [unwrap((i * step) % 2**32) for i in range(150)]  # 150 minutes, two wraps
    assert values == [i * step for i in range(150)]
