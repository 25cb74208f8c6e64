"""The daemon's numbers: what ``health`` publishes.

Written from the event loop thread only (the inference worker hands its
timings back through the loop), so no locks. Latencies go into small
fixed-size rings; percentiles are taken over the last ``size`` values.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
from scotti.firmware_protocol.assembly import AssemblerCounters
from scotti.firmware_protocol.framing import DecoderCounters
from scotti.firmware_protocol.pairing import FOOT_NAMES, PairingCounters


class LatencyRing:
    """The last ``size`` latencies in ms; p50/p90/p99/max over them."""

    def __init__(self, size: int = 1024) -> None:
        self._values = np.zeros(size, dtype=np.float64)
        self._next = 0
        self._count = 0

    def add(self, ms: float) -> None:
        self._values[self._next] = ms
        self._next = (self._next + 1) % len(self._values)
        self._count = min(self._count + 1, len(self._values))

    def summary(self) -> dict[str, float | int]:
        return latency_summary(self._values[: self._count])


def latency_summary(values: npt.ArrayLike) -> dict[str, float | int]:
    """n, p50, p90, p99 and max of latencies in ms (zeros when there are none)."""
    ms = np.asarray(values, dtype=np.float64)
    if not ms.size:
        return {"n": 0, "p50": 0.0, "p90": 0.0, "p99": 0.0, "max": 0.0}
    p50, p90, p99 = np.percentile(ms, [50, 90, 99])
    return {
        "n": int(ms.size),
        "p50": round(float(p50), 3),
        "p90": round(float(p90), 3),
        "p99": round(float(p99), 3),
        "max": round(float(ms.max()), 3),
    }


@dataclass
class Counters:
    """Everything counted between the port and the prediction."""

    started_mono_ns: int = field(default_factory=time.monotonic_ns)
    bytes_in: int = 0
    chunks_in: int = 0
    # The decoder's and the assembler's own counters, shared (the pipeline hands them
    # over once): read when a snapshot is taken, never copied per chunk.
    decoder: DecoderCounters = field(default_factory=DecoderCounters)
    assembly: AssemblerCounters = field(default_factory=AssemblerCounters)
    pairing: PairingCounters = field(default_factory=PairingCounters)
    board_status: int = 0  # BOARD_STATUS packets seen
    window_restarts: int = 0  # long gaps, reconnects and dropped frames start the window over
    dropped_frames: int = 0  # paired frames inference could not keep up with (oldest first)
    predictions: int = 0
    callback_errors: int = 0  # a consumer of predictions or states raised (logged, survived)
    connects: int = 0
    reconnects: int = 0  # connects after the first
    disconnects: int = 0
    queue_depth: int = 0  # paired frames waiting for the inference worker, now
    queue_depth_max: int = 0
    # The model step's time. The end-to-end latency (last byte in -> published) is the
    # publisher's to measure: health.end_to_end (docs/mqtt.md).
    inference_ms: LatencyRing = field(default_factory=LatencyRing)

    def observe_queue(self, depth: int) -> None:
        self.queue_depth = depth
        self.queue_depth_max = max(self.queue_depth_max, depth)

    def snapshot(self) -> dict[str, Any]:
        """Plain JSON-able numbers for ``health``."""
        p = self.pairing
        return {
            "uptime_s": round((time.monotonic_ns() - self.started_mono_ns) / 1e9, 3),
            "bytes_in": self.bytes_in,
            "chunks_in": self.chunks_in,
            "bad_packets": self.decoder.as_dict(),  # decoder counters by reason
            "assembler": self.assembly.as_dict(),
            "board_status_packets": self.board_status,
            "frames_in": {FOOT_NAMES[f]: p.frames_in[f] for f in (0, 1)},
            "held_frames": {FOOT_NAMES[f]: p.held[f] for f in (0, 1)},
            "filled_frames": {FOOT_NAMES[f]: p.filled[f] for f in (0, 1)},
            "pairing": {
                k: v for k, v in asdict(p).items() if k not in ("frames_in", "held", "filled")
            },
            "gaps": p.gaps,
            "window_restarts": self.window_restarts,
            "dropped_frames": self.dropped_frames,
            "predictions": self.predictions,
            "callback_errors": self.callback_errors,
            "connects": self.connects,
            "reconnects": self.reconnects,
            "disconnects": self.disconnects,
            "queue_depth": self.queue_depth,
            "queue_depth_max": self.queue_depth_max,
            "latency_ms": {"inference": self.inference_ms.summary()},
        }
