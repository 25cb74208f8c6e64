"""Transport effects: radio loss, USB arrival jitter, foot offset, clock drift, unplug.

Each edits a :class:`PacketSchedule` in place before anything is encoded, so
an effect changes exactly what it is about and nothing else: loss and unplug
only clear packets, jitter and offset only move host times, drift only
changes board clocks.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import Field, model_validator
from scotti.sim.effects.base import EffectParams, count_call
from scotti.sim.effects.schedule import PacketSchedule
from scotti.sim.effects.sensor import FOOT_INDEX


class PacketLossParams(EffectParams):
    """Bursty radio loss, a Gilbert-Elliott channel per insole.

    The link alternates good and bad states (geometric run lengths): it turns
    bad with ``p_good_to_bad`` and recovers with ``p_bad_to_good`` per radio
    packet (``unit="block"``, one row block) or per foot frame
    (``unit="frame"``: a frame's blocks are lost together). A packet is lost
    with ``loss_bad`` in the bad state and ``loss_good`` in the good one.
    Typical for BLE/2.4 GHz body-worn links: p_good_to_bad 0.001-0.02,
    p_bad_to_good 0.1-0.5, loss_bad 0.5-1, loss_good 0-0.001 (mean loss
    0.1-5 %).
    """

    p_good_to_bad: float = Field(0.005, ge=0.0, le=1.0)
    p_bad_to_good: float = Field(0.3, gt=0.0, le=1.0)
    loss_bad: float = Field(0.8, ge=0.0, le=1.0)
    loss_good: float = Field(0.0, ge=0.0, le=1.0)
    unit: Literal["block", "frame"] = "block"


class JitterParams(EffectParams):
    """Arrival jitter of host read times (scheduler, USB polling, radio retries).

    Every packet is delayed by a half-normal amount with ``std_ms``; bytes
    still arrive in order: a USB CDC pipe is one ordered byte stream, so a
    delayed packet holds up the ones behind it (head-of-line), it never
    overtakes. Typical 0.5-5 ms; 0..100.
    """

    std_ms: float = Field(2.0, ge=0.0, le=100.0)


class FootOffsetParams(EffectParams):
    """One insole's frames reach the host later (or earlier) by ``offset_ms``.

    The two insoles sample on their own timers; their phase relation is
    arbitrary. Typical -31..31 ms (half a frame); -1000..1000 accepted.
    """

    foot: Literal["left", "right"] = "right"
    offset_ms: float = Field(10.0, ge=-1000.0, le=1000.0)


class ClockDriftParams(EffectParams):
    """Crystal error of each insole's board clock, in parts per million.

    The board clock counter runs ``(1 + ppm * 1e-6)`` times true time; the
    frame schedule on the host is left as it is so that only the clocks
    change (the arrival drift, at most 0.36 s per hour at 100 ppm, is a
    ``foot_offset`` if wanted). Typical +-5..50 ppm; +-1000 accepted.
    """

    left_ppm: float = Field(20.0, ge=-1000.0, le=1000.0)
    right_ppm: float = Field(-15.0, ge=-1000.0, le=1000.0)


class UnplugParams(EffectParams):
    """The receiver is off USB from ``start_s`` for ``duration_s`` (session time).

    No byte arrives in that span; the receiver reboots on replug (its status
    uptime and counters restart). The insoles keep counting seq and clock.
    """

    start_s: float = Field(10.0, ge=0.0)
    duration_s: float = Field(2.0, gt=0.0, le=86_400.0)

    @model_validator(mode="after")
    def _finite(self) -> UnplugParams:
        if not np.isfinite(self.start_s + self.duration_s):
            msg = "start_s and duration_s must be finite"
            raise ValueError(msg)
        return self


def _gilbert_elliott_bad(
    steps: int, p_gb: float, p_bg: float, rng: np.random.Generator
) -> np.ndarray:
    """Bool (steps,): the bad state of a two-state chain, started in the good state.

    Built from alternating geometric run lengths, no per-step Python loop.
    """
    bad = np.zeros(steps, dtype=bool)
    if p_gb <= 0.0 or steps == 0:
        return bad
    pos = 0
    while pos < steps:  # a handful of rounds: each draws many runs at once
        expected = max(8, int(2 * steps * p_gb) + 8)
        good_runs = rng.geometric(p_gb, expected)
        bad_runs = rng.geometric(p_bg, expected)
        for g, b in zip(good_runs.tolist(), bad_runs.tolist(), strict=True):
            pos += g - 1  # the step that turns bad is itself bad
            if pos >= steps:
                break
            bad[pos : pos + b] = True
            pos += b
    return bad


def apply_packet_loss(p: PacketLossParams, s: PacketSchedule, rng: np.random.Generator) -> None:
    count_call("packet_loss")
    for foot in (0, 1):
        idx = np.flatnonzero(s.foot == foot)  # this insole's packets, in time order
        if p.unit == "frame":
            frames, step_of = np.unique(s.frame[idx], return_inverse=True)
            steps = len(frames)
        else:
            steps, step_of = len(idx), np.arange(len(idx))
        bad = _gilbert_elliott_bad(steps, p.p_good_to_bad, p.p_bad_to_good, rng)
        lost = rng.random(steps) < np.where(bad, p.loss_bad, p.loss_good)
        s.radio_lost[idx] |= lost[step_of]


def apply_jitter(p: JitterParams, s: PacketSchedule, rng: np.random.Generator) -> None:
    count_call("jitter")
    delay = np.abs(rng.standard_normal(len(s.t_ns))) * (p.std_ms * 1e6)
    order = np.argsort(s.t_ns, kind="stable")
    moved = s.t_ns[order] + np.rint(delay).astype(np.int64)
    s.t_ns[order] = np.maximum.accumulate(moved)  # in order: no overtaking


def apply_foot_offset(p: FootOffsetParams, s: PacketSchedule) -> None:
    count_call("foot_offset")
    s.t_ns[s.foot == FOOT_INDEX[p.foot]] += round(p.offset_ms * 1e6)


def apply_clock_drift(p: ClockDriftParams, s: PacketSchedule) -> None:
    count_call("clock_drift")
    for foot, ppm in ((0, p.left_ppm), (1, p.right_ppm)):
        sel = s.foot == foot
        start = s.clock_start_us[foot]
        elapsed = s.board_clock_us[sel] - start
        s.board_clock_us[sel] = start + np.rint(elapsed * (1.0 + ppm * 1e-6)).astype(np.int64)


def apply_unplug(p: UnplugParams, s: PacketSchedule) -> None:
    count_call("unplug")
    start = s.t0_ns + round(p.start_s * 1e9)
    end = start + round(p.duration_s * 1e9)
    s.unplugged |= (s.t_ns >= start) & (s.t_ns < end)


def unplug_spans_ns(params: list[UnplugParams], t0_ns: int) -> list[tuple[int, int]]:
    """(start, end) host ns of each unplug, for the receiver's reboots."""
    spans = []
    for p in params:
        start = t0_ns + round(p.start_s * 1e9)
        spans.append((start, start + round(p.duration_s * 1e9)))
    return sorted(spans)
