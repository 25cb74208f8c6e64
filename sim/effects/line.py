"""Serial-line corruption: bit flips in the byte stream and garbage bursts.

Acts on the encoded bytes as they go to the session file, after all other
effects: what a noisy USB-serial bridge or a flaky UART between the radio
chip and the USB chip would deliver. Packets it does not touch keep their
exact bytes.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field
from scotti.sim.effects.base import EffectParams, count_call


class LineCorruptionParams(EffectParams):
    """Bit errors and bursts of garbage on the serial line.

    ``flip_rate_per_byte``: probability that a byte arrives with one random
    bit flipped (typ. 1e-7 on USB, 1e-5..1e-4 on a noisy UART; 0..0.1).
    ``garbage_per_s``: rate of garbage bursts (a Poisson process; typ.
    0..0.1 per s, e.g. a boot banner or a glitch; 0..100), each
    ``garbage_min_bytes..garbage_max_bytes`` uniformly random bytes inserted
    between two packets as their own read.
    """

    flip_rate_per_byte: float = Field(1e-5, ge=0.0, le=0.1)
    garbage_per_s: float = Field(0.0, ge=0.0, le=100.0)
    garbage_min_bytes: int = Field(1, ge=1, le=4096)
    garbage_max_bytes: int = Field(64, ge=1, le=4096)


class LineCorruption:
    """Stateful stream transform: ``process(t_ns, data)`` -> the reads to record."""

    def __init__(self, p: LineCorruptionParams, rng: np.random.Generator, t0_ns: int) -> None:
        self.p = p
        self.rng = rng
        self.flips = 0
        self.garbage_bursts = 0
        self._to_next_flip = self._gap()  # bytes until the next corrupted byte
        self._next_burst_ns = self._burst_after(t0_ns)

    def _gap(self) -> int:
        rate = self.p.flip_rate_per_byte
        return int(self.rng.geometric(rate)) - 1 if rate > 0 else -1

    def _burst_after(self, t_ns: int) -> int:
        rate = self.p.garbage_per_s
        if rate <= 0:
            return -1
        return t_ns + round(float(self.rng.exponential(1.0 / rate)) * 1e9)

    def process(self, t_ns: int, data: bytes) -> list[tuple[int, bytes]]:
        count_call("line_corruption")
        out: list[tuple[int, bytes]] = []
        while 0 <= self._next_burst_ns <= t_ns:
            low = self.p.garbage_min_bytes
            high = max(low, self.p.garbage_max_bytes)
            n = int(self.rng.integers(low, high + 1))
            out.append((t_ns, self.rng.integers(0, 256, n, dtype=np.uint8).tobytes()))
            self.garbage_bursts += 1
            self._next_burst_ns = self._burst_after(self._next_burst_ns)
        if 0 <= self._to_next_flip < len(data):
            buf = bytearray(data)
            pos = self._to_next_flip
            while 0 <= pos < len(buf):
                buf[pos] ^= 1 << int(self.rng.integers(0, 8))
                self.flips += 1
                pos += 1 + self._gap()
            self._to_next_flip = pos - len(buf)
            data = bytes(buf)
        elif self._to_next_flip >= 0:
            self._to_next_flip -= len(data)
        out.append((t_ns, data))
        return out
