"""``scotti session info FILE [--json]``: what a session file holds.

Source, device, geometry, duration; per foot the row blocks, frames,
incomplete frames and sequence gaps; bad packets by reason; the pairs the
daemon would make (held, zero-filled, gaps, restarts); labels; the
board's status reports; the events marked while recording; whether the file was
cut short.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Sequence
from typing import Any

from scotti.firmware_protocol.errors import SessionError
from scotti.firmware_protocol.packets import InsoleStatus
from scotti.firmware_protocol.session_summary import EVENTS_KEPT, SessionSummary, summarize

_FOOT_ROWS = (
    ("row blocks", "blocks"),
    ("frames", "frames"),
    ("incomplete frames", "incomplete_frames"),
    ("rows missing", "rows_missing"),
    ("sequence gaps", "gaps"),
    ("frames lost in gaps", "frames_lost"),
    ("first seq", "first_seq"),
    ("last seq", "last_seq"),
    ("other geometry", "other_geometry"),
)
EVENTS_SHOWN = 20  # marked events listed by name; the rest counted
_DECODER_ERRORS = ("bad_cobs", "bad_crc", "too_long", "bad_version", "unknown_type", "malformed")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    info = sub.add_parser("info", help="summarise a session file")
    info.add_argument("file", metavar="FILE", help="a session file (.scotti)")
    info.add_argument("--json", action="store_true", help="print one JSON object instead")
    # Listed for --help only: `scotti session export` and `relabel` run the model's room, so
    # the command line (cli/main.py) hands them to their modules before they reach here.
    sub.add_parser(
        "export", help="FILE --mcap OUT.mcap [--force]: predictions as a Foxglove recording"
    )
    sub.add_parser(
        "relabel", help="SESSION... --out DIR: simulated sessions' progress labels remade"
    )


def run(args: argparse.Namespace) -> int:
    try:
        summary = summarize(args.file)
    except SessionError as exc:
        print(f"scotti session: {exc}", file=sys.stderr)
        return 2
    names = getattr(args, "action_names", ())  # the model contract's, handed in by cli/main.py
    text = (
        json.dumps(summary.as_dict(), indent=2, default=str)
        if args.json
        else render(summary, names)
    )
    try:
        print(text, flush=True)
    except BrokenPipeError:  # `scotti session info F | head`: the reader left, not an error
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    return 0


def _insole(insole: InsoleStatus) -> str:
    mv = "? mV" if insole.battery_mv is None else f"{insole.battery_mv} mV"
    pct = "? %" if insole.battery_pct is None else f"{insole.battery_pct} %"
    rssi = "? dBm" if insole.rssi_dbm is None else f"{insole.rssi_dbm} dBm"
    link = "up" if insole.link_up else "DOWN"
    return f"{mv} {pct}, {rssi}, link {link}, {insole.packets_lost} radio packets lost"


def _scene(scene: dict[str, Any] | None) -> str:
    if not scene:
        return "-"
    simple = [f"{k}={v}" for k, v in scene.items() if isinstance(v, str | int | float | bool)]
    more = len(scene) - len(simple)
    return " ".join(simple) + (f" (+{more} more)" if more else "")


def _imported(info: dict[str, Any]) -> str:
    """Where an imported session came from, in one line."""
    parts = []
    p = info.get("pressure") or {}
    if p and p.get("format", "table") != "table":  # a vendor's export: its format, units
        parts.append(
            f"{p.get('file')} ({p.get('format')}, {p.get('units')}, {p.get('frames')} frames at"
            f" {float(p.get('rate_hz') or 0):.3g} Hz)"
        )
    elif p:
        parts.append(
            f"{p.get('file')} ({p.get('rows')} x {p.get('cols')}, {p.get('frames')} frames at"
            f" {float(p.get('rate_hz') or 0):.3g} Hz)"
        )
    for foot in p.get("absent_feet") or []:
        parts.append(f"{foot} foot absent (one-foot recording: no {foot} packets)")
    counts = info.get("counts") or {}
    if counts:
        parts.append(f"counts {counts.get('method')}")
    k = info.get("keypoints") or {}
    if k:
        parts.append(
            f"keypoints {k.get('file')} ({k.get('set')}, {len(k.get('mapped', []))} of 19)"
        )
    labels = info.get("labels") or {}
    if labels:
        parts.append("labels " + ", ".join(f"{a}={b}" for a, b in labels.items()))
    segments = info.get("segments") or []
    if len(segments) > 1:
        parts.append(f"{len(segments)} segments")
    return "; ".join(parts) or "-"


def _pairs(p: dict[str, Any]) -> str:
    """What the daemon's pairing would make of the frames (firmware_protocol/pairing.py)."""
    held, filled = p.get("held", [0, 0]), p.get("filled", [0, 0])
    return (
        f"pairs     {p.get('pairs_out', 0)} as the daemon pairs them; held left {held[0]},"
        f" right {held[1]}; zero-filled left {filled[0]}, right {filled[1]};"
        f" gaps bridged {p.get('gaps', 0)}, window restarts {p.get('restarts', 0)},"
        f" board resyncs {p.get('resyncs', 0)}"
    )


def _action(index: int, names: Sequence[str]) -> str:
    if index < 0:
        return "none"
    return names[index] if index < len(names) else f"action {index}"


def render(s: SessionSummary, action_names: Sequence[str] = ()) -> str:
    """The human-readable report; labels by name when ``action_names`` are given.

    The file holds action indices; their names are the model contract's, which this
    room must not import (ARCHITECTURE.md), so the command line hands them in.
    """
    h = s.header
    created = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime(h.created_unix))
    if h.created_unix == 0:  # the simulator writes 0: reruns are bit-identical
        created = "- (simulated files carry no wall clock)"
    lines = [
        f"session   {s.path}",
        f"format    {h.format_version}, {h.source}, device {h.device!r}, created {created}",
        f"geometry  {h.rows} x {h.cols}, {h.sample_bits}-bit samples, {h.rate_hz:g} Hz",
    ]
    if h.source == "simulated" or h.scene:
        lines.append(f"scene     {_scene(h.scene)}")
    if h.imported:
        lines.append(f"import    {_imported(h.imported)}")
    lines.append(
        f"duration  {s.duration_s:.2f} s, {s.packet_records} packet records,"
        f" {s.stream_bytes} stream bytes, file {s.file_bytes} bytes"
    )
    lines.append(f"{'':22}{'left':>10}{'right':>10}")
    left, right = s.feet["left"], s.feet["right"]
    for title, key in _FOOT_ROWS:
        values = [getattr(left, key), getattr(right, key)]
        cells = ["-" if v is None else str(v) for v in values]
        lines.append(f"  {title:20}{cells[0]:>10}{cells[1]:>10}")
    rates = ["-" if f.rate_hz is None else f"{f.rate_hz:.2f}" for f in (left, right)]
    lines.append(f"  {'frame rate (Hz)':20}{rates[0]:>10}{rates[1]:>10}")
    bad = [f"{k}={s.decoder[k]}" for k in _DECODER_ERRORS if s.decoder.get(k)]
    lines.append(
        f"bad packets {', '.join(bad) or 'none'}"
        f" ({s.decoder.get('bytes_discarded', 0)} bytes discarded)"
    )
    dropped = [
        f"{k}={v}"
        for k, v in s.assembler.items()
        if k in ("duplicate_blocks", "late_blocks", "geometry_mismatches", "restarts") and v
    ]
    if dropped:
        lines.append(f"assembly  {', '.join(dropped)}")
    lines.append(_pairs(s.pairing))
    labels = s.labels
    if labels.count:
        actions = ", ".join(
            f"{_action(a, action_names)}: {n}" for a, n in sorted(labels.actions.items())
        )
        lines.append(
            f"labels    {labels.count} (seq {labels.first_seq}..{labels.last_seq}); {actions}"
        )
    else:
        lines.append("labels    none")
    events = s.events.as_dict(s.first_packet_ns)
    if events["count"]:
        lines.append(f"events    {events['count']}")
        for e in events["first"][:EVENTS_SHOWN]:
            detail = f" ({e['detail']})" if e["detail"] else ""
            lines.append(f"  {e['at_s']:>9.3f} s  {e['label']}{detail}")
        if events["count"] > EVENTS_SHOWN:
            lines.append(
                f"  ... {events['count'] - EVENTS_SHOWN} more (--json lists {EVENTS_KEPT})"
            )
    last = s.status.last
    if last is None:
        lines.append("status    no board status reports")
    else:
        lines.append(
            f"status    {s.status.reports} reports; receiver up {last.uptime_s} s,"
            f" {last.rx_packets} radio packets, {last.radio_crc_errors} radio CRC errors,"
            f" {last.overflows} overflows"
        )
        lines.append(f"  left    {_insole(last.left)}")
        lines.append(f"  right   {_insole(last.right)}")
    if s.truncated:
        lines.append(
            f"file      TRUNCATED: cut inside a record; read up to byte {s.whole_record_bytes}"
        )
    else:
        lines.append("file      complete (ends on a whole record)")
    if s.bad_records or s.unknown_records:
        lines.append(
            f"records   {s.bad_records} unreadable, {s.unknown_records} of unknown kind (skipped)"
        )
    return "\n".join(lines)
