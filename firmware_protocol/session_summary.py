"""What a session file holds, in numbers: the facts behind ``scotti session info``.

The packets go through the daemon's own frame path (``frame_path``), so the
counts here, the pairs included, are what a replay of the file would see.
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass, field
from typing import Any

from scotti.firmware_protocol.assembly import FootFrame
from scotti.firmware_protocol.frame_path import FramePath, FrameWatch
from scotti.firmware_protocol.packets import BoardStatus, Foot, FrameRows
from scotti.firmware_protocol.session import (
    EventRecord,
    LabelRecord,
    PacketRecord,
    SessionHeader,
    SessionReader,
)
from scotti.firmware_protocol.wrap import seq_delta


@dataclass
class FootSummary:
    """One insole's stream as the host assembled it."""

    blocks: int = 0  # FRAME_ROWS packets
    frames: int = 0  # assembled foot frames, complete or not
    incomplete_frames: int = 0
    rows_missing: int = 0  # rows missing across the incomplete frames
    gaps: int = 0  # places where the sequence skipped forward
    frames_lost: int = 0  # sequence numbers skipped across all gaps (wrap-aware)
    first_seq: int | None = None
    last_seq: int | None = None
    other_geometry: int = 0  # frames whose geometry differs from the header's
    rate_hz: float | None = None  # frames per second of host time
    _first_ns: int = field(default=0, repr=False)
    _last_ns: int = field(default=0, repr=False)

    def add(self, frame: FootFrame, geometry: tuple[int, int, int]) -> None:
        self.frames += 1
        if not frame.complete:
            self.incomplete_frames += 1
            self.rows_missing += frame.missing_count
        if (frame.rows, frame.cols, frame.sample_bits) != geometry:
            self.other_geometry += 1
        if self.last_seq is not None:
            step = seq_delta(frame.seq, self.last_seq)
            if step > 1:
                self.gaps += 1
                self.frames_lost += step - 1
        else:
            self.first_seq = frame.seq
            self._first_ns = frame.last_byte_ns
        self.last_seq = frame.seq
        self._last_ns = frame.last_byte_ns
        if self.frames > 1 and self._last_ns > self._first_ns:
            self.rate_hz = (self.frames - 1) / ((self._last_ns - self._first_ns) / 1e9)

    def as_dict(self) -> dict[str, Any]:
        return {k: v for k, v in asdict(self).items() if not k.startswith("_")}


@dataclass
class LabelSummary:
    count: int = 0
    actions: dict[int, int] = field(default_factory=dict)  # action index (-1 none) -> labels
    first_seq: int | None = None
    last_seq: int | None = None

    def add(self, label: LabelRecord) -> None:
        self.count += 1
        self.actions[label.action] = self.actions.get(label.action, 0) + 1
        if self.first_seq is None:
            self.first_seq = label.seq
        self.last_seq = label.seq


EVENTS_KEPT = 100  # events listed in a summary; the rest only counted (bounded memory)


@dataclass
class EventSummary:
    """The events marked while recording (``event/mark``): how many, and the first ones."""

    count: int = 0
    first: list[EventRecord] = field(default_factory=list)

    def add(self, event: EventRecord) -> None:
        self.count += 1
        if len(self.first) < EVENTS_KEPT:
            self.first.append(event)

    def as_dict(self, start_ns: int | None) -> dict[str, Any]:
        """``at_s``: seconds from the first packet record (from the first event without one)."""
        origin = start_ns if start_ns is not None else (self.first[0].t_ns if self.first else 0)
        return {
            "count": self.count,
            "first": [
                {
                    "at_s": round((e.t_ns - origin) / 1e9, 3),
                    "label": e.label,
                    "detail": e.detail,
                    "wall_ns": e.wall_ns,
                }
                for e in self.first
            ],
        }


@dataclass
class StatusSummary:
    reports: int = 0
    last: BoardStatus | None = None
    lowest_battery_pct: dict[str, int | None] = field(
        default_factory=lambda: {"left": None, "right": None}
    )
    link_down_reports: dict[str, int] = field(default_factory=lambda: {"left": 0, "right": 0})

    def add(self, status: BoardStatus) -> None:
        self.reports += 1
        self.last = status
        for side, foot in (("left", Foot.LEFT), ("right", Foot.RIGHT)):
            insole = status.insole(foot)
            low = self.lowest_battery_pct[side]
            if insole.battery_pct is not None and (low is None or insole.battery_pct < low):
                self.lowest_battery_pct[side] = insole.battery_pct
            if not insole.link_up:
                self.link_down_reports[side] += 1

    def as_dict(self) -> dict[str, Any]:
        return {
            "reports": self.reports,
            "last": None if self.last is None else self.last.as_dict(),
            "lowest_battery_pct": self.lowest_battery_pct,
            "link_down_reports": self.link_down_reports,
        }


@dataclass
class SessionSummary:
    path: str
    header: SessionHeader
    file_bytes: int = 0
    whole_record_bytes: int = 0  # bytes up to the end of the last whole record
    packet_records: int = 0
    stream_bytes: int = 0
    duration_s: float = 0.0  # host time from the first to the last packet record
    feet: dict[str, FootSummary] = field(
        default_factory=lambda: {"left": FootSummary(), "right": FootSummary()}
    )
    decoder: dict[str, int] = field(default_factory=dict)
    assembler: dict[str, int] = field(default_factory=dict)
    pairing: dict[str, Any] = field(default_factory=dict)  # the pairs a replay would make
    labels: LabelSummary = field(default_factory=LabelSummary)
    events: EventSummary = field(default_factory=EventSummary)
    first_packet_ns: int | None = None  # host time of the first packet record
    status: StatusSummary = field(default_factory=StatusSummary)
    truncated: bool = False
    bad_records: int = 0
    unknown_records: int = 0

    def as_dict(self) -> dict[str, Any]:
        return {
            "path": self.path,
            "header": {k: v for k, v in self.header.to_record().items() if k != "kind"},
            "file_bytes": self.file_bytes,
            "whole_record_bytes": self.whole_record_bytes,
            "packet_records": self.packet_records,
            "stream_bytes": self.stream_bytes,
            "duration_s": self.duration_s,
            "feet": {side: foot.as_dict() for side, foot in self.feet.items()},
            "decoder": self.decoder,
            "assembler": self.assembler,
            "pairing": self.pairing,
            "labels": {
                "count": self.labels.count,
                "actions": {str(k): v for k, v in sorted(self.labels.actions.items())},
                "first_seq": self.labels.first_seq,
                "last_seq": self.labels.last_seq,
            },
            "events": self.events.as_dict(self.first_packet_ns),
            "status": self.status.as_dict(),
            "truncated": self.truncated,
            "bad_records": self.bad_records,
            "unknown_records": self.unknown_records,
        }


class _Counting(FrameWatch):
    """Blocks, foot frames and status reports into the summary, per foot."""

    def __init__(self, summary: SessionSummary) -> None:
        header = summary.header
        self.geometry = (header.rows, header.cols, header.sample_bits)
        self.feet = {Foot.LEFT: summary.feet["left"], Foot.RIGHT: summary.feet["right"]}
        self.summary = summary

    def block(self, block: FrameRows) -> None:
        self.feet[block.foot].blocks += 1

    def frame(self, frame: FootFrame) -> None:
        self.feet[frame.foot].add(frame, self.geometry)

    def status(self, status: BoardStatus) -> None:
        self.summary.status.add(status)  # DecodeError values are in the decoder's counters


def summarize(path: str | os.PathLike[str]) -> SessionSummary:
    """Read a whole session file and count what it holds; raises ``SessionError``."""
    with SessionReader(path, events=True) as reader:
        summary = SessionSummary(str(path), reader.header)
        frame_path = FramePath(watch=_Counting(summary))
        first_ns: int | None = None
        last_ns = 0
        for record in reader.records():
            if isinstance(record, LabelRecord):
                summary.labels.add(record)
                continue
            if isinstance(record, EventRecord):
                summary.events.add(record)
                continue
            if not isinstance(record, PacketRecord):
                continue  # source frames: not asked for, never yielded
            summary.packet_records += 1
            summary.stream_bytes += len(record.data)
            first_ns = record.t_ns if first_ns is None else first_ns
            last_ns = record.t_ns
            frame_path.feed(record.data, record.t_ns)
        frame_path.end()
    summary.file_bytes = os.stat(path).st_size
    summary.whole_record_bytes = reader.bytes_read
    summary.first_packet_ns = first_ns
    summary.duration_s = 0.0 if first_ns is None else (last_ns - first_ns) / 1e9
    decoder = frame_path.decoder
    summary.decoder = decoder.counters.as_dict() | {"pending_at_end": decoder.pending}
    summary.assembler = frame_path.assembler.counters.as_dict()
    summary.pairing = asdict(frame_path.pairing.counters)
    summary.truncated = reader.truncated
    summary.bad_records = reader.bad_records
    summary.unknown_records = reader.unknown_records
    return summary
