"""The bench's view of the daemon's process tree: CPU, memory, threads, descriptors.

psutil (the ``[bench]`` extra) samples the daemon (its supervisor and workers
together with ``processes`` > 1) over the measured seconds, and from its start to
the end of the run the peaks that a unit's MemoryMax, TasksMax and LimitNOFILE must
allow (docs/deploy.md).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import psutil
from scotti.daemon.tools.bench_subscriber import READY_TIMEOUT_S


@dataclass
class Peaks:
    """The most a daemon (its processes together) held at once since it started."""

    rss_mib: float = 0.0
    threads: int = 0  # what systemd's TasksMax counts
    fds: int = 0  # open descriptors, what LimitNOFILE bounds (per process: the largest)

    def update(self, tree: list[psutil.Process]) -> None:
        held = [_held(p) for p in tree]
        self.rss_mib = max(self.rss_mib, sum(h[0] for h in held) / 2**20)
        self.threads = max(self.threads, sum(h[1] for h in held))
        self.fds = max(self.fds, max((h[2] for h in held), default=0))


def sample_process(
    pid: int,
    seconds: float,
    warmup: float | threading.Event,
    others: tuple[int, ...] = (),
    peaks: Peaks | None = None,
) -> tuple[float, float, float]:
    """Mean CPU % (100 = one core) and peak RSS in MiB of ``pid`` and its children (a
    daemon with ``processes`` > 1: the supervisor and its workers, RSS summed) over
    ``seconds`` after ``warmup`` (seconds, or an event: once it is set), and the CPU %
    of ``others`` together (the bench's own load on the host). ``peaks``: updated from
    now (the daemon's start) to the end, the model load and every connection included."""
    proc = psutil.Process(pid)
    rest = [psutil.Process(p) for p in others]
    peaks = peaks if peaks is not None else Peaks()
    if isinstance(warmup, threading.Event):
        ready, until = warmup, time.monotonic() + READY_TIMEOUT_S + seconds
    else:
        ready, until = threading.Event(), time.monotonic() + warmup
    while not ready.wait(0.2) and time.monotonic() < until:
        peaks.update([proc, *_children(proc)])
    tree = [proc, *_children(proc)]  # workers are up once poses flow
    for p in (*tree, *rest):
        p.cpu_percent(None)
    rss, end = 0, time.monotonic() + seconds
    while time.monotonic() < end:
        time.sleep(0.5)
        rss = max(rss, sum(_rss(p) for p in tree))
        peaks.update(tree)
    cpu = sum(_cpu(p) for p in tree)
    return cpu, rss / 2**20, sum(p.cpu_percent(None) for p in rest)


def _children(proc: psutil.Process) -> list[psutil.Process]:
    try:
        return list(proc.children(recursive=True))
    except psutil.NoSuchProcess:
        return []


def _held(proc: psutil.Process) -> tuple[int, int, int]:
    """(RSS bytes, threads, open descriptors) of ``proc``; zeros once it is gone."""
    try:
        with proc.oneshot():
            return int(proc.memory_info().rss), proc.num_threads(), proc.num_fds()
    except psutil.NoSuchProcess:
        return 0, 0, 0


def _rss(proc: psutil.Process) -> int:
    try:
        return int(proc.memory_info().rss)
    except psutil.NoSuchProcess:  # a worker that died (it is started again)
        return 0


def _cpu(proc: psutil.Process) -> float:
    try:
        return float(proc.cpu_percent(None))
    except psutil.NoSuchProcess:
        return 0.0
