"""A day of stream at full speed: does the daemon's memory stay flat?

Generates 24 hours of 16 Hz frame pairs (1,382,400) as the receiver would send
them (row blocks, COBS, CRC; seqs and board clocks counting and wrapping as in
a real day: the u16 seq wraps 21 times, the u32 microsecond clock 20 times)
and feeds them through the real ``Daemon`` (decode, assemble, pair, window,
onnxruntime, payloads, publisher into a real mosquitto). The source is not
live, so the pipeline paces it: nothing is dropped for speed. Every
``--every`` frames it prints the process's RSS; at the end, the growth from
the first report (the daemon warmed up) to the last.

    python -m scotti.daemon.tools.day_soak [--frames 1382400] [--model PATH]

A measurement, never a test; the figure in docs/reliability.md comes from it.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import sys
import time
from collections.abc import AsyncGenerator
from pathlib import Path
from typing import Final

from scotti.daemon.input.sources import Source, SourceEvent, SourceItem
from scotti.daemon.service.app import Daemon
from scotti.daemon.settings import (
    ConfigError,
    DeviceSettings,
    Settings,
    default_model_path,
    load_settings,
)
from scotti.daemon.tools import plain_help
from scotti.daemon.tools.generated import GeneratedBoard
from scotti.daemon.tools.local_broker import BrokerError, Mosquitto
from scotti.models.contract import FRAME_RATE_HZ
from scotti.models.errors import ModelError
from scotti.models.kv_streaming import StepModel, open_step_model

DAY_FRAMES: Final = round(24 * 3600 * FRAME_RATE_HZ)  # 1,382,400
_YIELD_EVERY: Final = 32  # frames between turns given to the event loop
_BATCH: Final = 256  # frames generated (and COBS-encoded) at once


def rss_mib() -> float:
    """Resident set size of this process in MiB (Linux /proc)."""
    with open("/proc/self/statm", encoding="ascii") as f:
        pages = int(f.read().split()[1])
    return pages * os.sysconf("SC_PAGE_SIZE") / 2**20


class DaySource:
    """``frames`` frame pairs from a ``GeneratedBoard``, made as they are read."""

    live = False

    def __init__(
        self, frames: int, every: int, report: ReportTable, deadline: float = float("inf")
    ) -> None:
        self.frames = frames
        self.deadline = deadline  # time.monotonic() at which to end early (a budget)
        self.ended_at = frames
        self.every = every
        self.report = report
        self.name = f"generated day ({frames} frames)"
        self._board = GeneratedBoard()

    def chunks(self, first: int, count: int) -> list[bytes]:
        return self._board.chunks(first, count)

    async def stream(self) -> AsyncGenerator[SourceItem, None]:
        yield SourceEvent("connected", "generated day")
        for first in range(0, self.frames, _BATCH):
            if time.monotonic() > self.deadline:
                self.ended_at = first
                break
            count = min(_BATCH, self.frames - first)
            for k, chunk in enumerate(self.chunks(first, count)):
                i = first + k
                if i % _YIELD_EVERY == 0:
                    await asyncio.sleep(0)
                if i % self.every == 0 and i:
                    self.report.row(i)
                yield time.monotonic_ns(), chunk
        self.report.row(self.ended_at)
        yield SourceEvent("disconnected", "end of the generated day")


class ReportTable:
    """Prints one line per ``--every`` frames: frames, predictions, RSS, rate."""

    def __init__(self) -> None:
        self.daemon: Daemon | None = None
        self.rss: list[tuple[int, float]] = []
        self._start = time.monotonic()

    def header(self) -> None:
        print(f"{'frames':>9} {'predictions':>11} {'published':>9} {'RSS MiB':>8} {'frames/s':>8}")

    def row(self, frames: int) -> None:
        if self.rss and self.rss[-1][0] == frames:
            return  # the last regular report was at the very end
        rss = rss_mib()
        self.rss.append((frames, rss))
        predictions = published = 0
        if self.daemon is not None:
            predictions = self.daemon.counters.predictions
            publisher = self.daemon.publisher
            published = publisher.stats.published if publisher is not None else 0
        rate = frames / max(time.monotonic() - self._start, 1e-9)
        line = f"{frames:>9} {predictions:>11} {published:>9} {rss:>8.1f} {rate:>8.0f}"
        print(line, flush=True)


class SoakDaemon(Daemon):
    """The real daemon, reading the generated day instead of a port."""

    def __init__(self, settings: Settings, runtime: StepModel, source: DaySource) -> None:
        super().__init__(settings, runtime)
        self._day = source

    def _make_source(self, device: DeviceSettings) -> Source:
        return self._day


def run(args: argparse.Namespace) -> int:
    model = args.model or default_model_path()
    runtime = open_step_model(model, threads=1)  # either form, as the daemon
    report = ReportTable()
    budget = args.max_minutes * 60 if args.max_minutes > 0 else float("inf")
    source = DaySource(args.frames, args.every, report, time.monotonic() + budget)
    with Mosquitto() as broker:
        settings = load_settings(
            {
                "source": {"port": "generated"},  # replaced by SoakDaemon._make_source
                "model": {"path": model},
                "mqtt": {"broker": broker.url, "device_id": "day-soak"},
                "log_level": "warning",
            }
        )
        daemon = SoakDaemon(settings, runtime, source)
        report.daemon = daemon
        print(
            f"day soak: {args.frames} frame pairs at full speed through the daemon "
            f"(model {model.name}, broker {broker.url}); RSS every {args.every} frames"
        )
        report.header()
        started = time.monotonic()
        code = asyncio.run(daemon.run())
    elapsed = time.monotonic() - started
    first, last = report.rss[0], report.rss[-1]
    peak = max(r for _, r in report.rss)
    print(
        f"RSS at {first[0]} frames {first[1]:.1f} MiB, at {last[0]} frames {last[1]:.1f} MiB: "
        f"growth {last[1] - first[1]:+.1f} MiB (peak {peak:.1f} MiB); "
        f"{daemon.counters.predictions} predictions in {elapsed / 60:.1f} min"
    )
    if source.ended_at < args.frames:
        print(f"stopped by --max-minutes after {source.ended_at} of {args.frames} frames")
    return code


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m scotti.daemon.tools.day_soak", description=plain_help(__doc__)
    )
    p.add_argument("--frames", type=int, default=DAY_FRAMES, help="frame pairs (default: a day)")
    p.add_argument("--every", type=int, default=100_000, help="frames between RSS reports")
    p.add_argument("--model", type=Path, help="ONNX step graph (default: the shipped one)")
    p.add_argument("--max-minutes", type=float, default=0.0, help="time budget (0: none)")
    args = p.parse_args(argv)
    if args.frames < 1 or args.every < 1:
        print("day_soak: --frames and --every must be positive", file=sys.stderr)
        return 2
    try:
        return run(args)
    except (ConfigError, ModelError, BrokerError) as exc:
        print(f"day_soak: {exc}", file=sys.stderr)
        return 78


if __name__ == "__main__":
    sys.exit(main())
