"""What the publisher counts: health's ``published``, ``dropped`` and ``pipeline.publish``."""

from __future__ import annotations

from dataclasses import dataclass, field

from scotti.daemon.service.counters import LatencyRing


@dataclass
class PublisherStats:
    published: int = 0  # predictions fully published
    dropped_full: int = 0  # pushed out of the queue by newer ones
    dropped_stale: int = 0  # older than the message expiry when the broker came back
    dropped_error: int = 0  # lost in a publish that failed
    connects: int = 0
    last_error: str = ""  # why the broker connection last failed, one line
    outages: int = 0  # times the broker was found away (at start, or lost)
    unreachable_s: float = 0.0  # seconds without the broker, over the outages that ended
    last_seq: int | None = None
    latency_ms: LatencyRing = field(default_factory=LatencyRing)  # last byte -> publish
    not_acknowledging: int = 0  # connections dropped: a publish unanswered too long
    refused: int = 0  # QoS 1 publishes the broker refused (PUBACK reason code >= 0x80)
    last_refused: str = ""  # the topic and reason of the latest refusal
    status_restored: int = 0  # times another client's status on our topic was replaced

    @property
    def dropped(self) -> int:
        return self.dropped_full + self.dropped_stale + self.dropped_error

    @property
    def reconnects(self) -> int:
        return max(0, self.connects - 1)
