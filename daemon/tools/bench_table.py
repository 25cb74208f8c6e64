"""The bench's results: one row per run, printed as markdown tables."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from scotti.daemon.service.counters import latency_summary
from scotti.daemon.tools.bench_model import core_share_per_pair
from scotti.daemon.tools.bench_process import Peaks
from scotti.daemon.tools.bench_subscriber import OOD_FLAGS
from scotti.models.contract import FRAME_RATE_HZ

GOAL_P99_MS = 1e3 / FRAME_RATE_HZ  # a subscriber should have each pose within one frame
GOAL_RATIO = 1.5  # issue 42: the daemon's CPU per pair at most 1.5x the model's own


def percentiles(values: list[float]) -> str:
    s = latency_summary(values)
    if not s["n"]:
        return "no samples"
    return f"p50 {s['p50']:6.2f}  p90 {s['p90']:6.2f}  p99 {s['p99']:6.2f}  max {s['max']:6.2f} ms"


@dataclass(frozen=True)
class Row:
    pairs: int
    batch: bool
    processes: int  # the daemon's worker processes (1: all in one)
    published: int  # poses the subscriber got in the measured seconds
    seconds: float
    publish: dict[str, float | int]  # the daemon's latency_ms
    receipt: dict[str, float | int]  # last byte -> subscriber
    cpu: float  # the daemon (and its workers), % of one core
    rss: float  # the daemon (and its workers, summed), MiB
    bench_cpu: float  # the boards, the subscriber and mosquitto, % of one core
    load: float  # 1-minute load average at the end
    peaks: Peaks  # from the daemon's start to the end of the run
    everything: bool = False  # remote control and (one process) the web and Foxglove servers
    model_ms: float = 0.0  # the model step's CPU ms per frame at this row's batch size
    flagged: dict[str, float] = field(default_factory=dict)  # OOD flag -> share 0..1
    dropped: int = 0  # foot frames the daemon did not take from its ports in time
    profile: str = ""  # bench --profile: the daemon's CPU by part of the path
    gather_ms: float = 0.0  # inference.gather_ms of the run
    daemon_from: Path | None = None  # another checkout's daemon ran (bench --daemon-from)
    frames_per_call: float = 0.0  # the engine's, from the devices' health (0: not said)

    @property
    def rate(self) -> float:
        """Poses per second per pair (16 = every frame)."""
        return self.published / self.seconds / self.pairs

    @property
    def cpu_per_pair(self) -> float:
        return self.cpu / self.pairs

    @property
    def model_per_pair(self) -> float:
        """% of a core the model alone needs per pair at 16 Hz (at this row's batch)."""
        return core_share_per_pair(self.model_ms)

    @property
    def ratio(self) -> float:
        """The daemon's CPU per pair over the model's (issue 42: at most 1.5)."""
        return self.cpu_per_pair / self.model_per_pair if self.model_ms > 0 else float("nan")


HEADER = (
    "| pairs | inference | poses/s per pair | publish p50 / p99 ms "
    "| subscriber p50 / p99 ms | frames per model call | daemon CPU % of a core | per pair "
    "| model per pair "
    "| daemon / model | RSS MiB | bench's own CPU % | flagged out_of_range / unloaded "
    "/ unfamiliar % | load avg |"
)
COLUMNS = HEADER.count("|") - 1


def table_row(r: Row) -> str:
    mode = "batched" if r.batch else "per pair"
    if r.processes > 1:
        mode += f", {r.processes} processes"
    if r.daemon_from is not None:
        mode += f", daemon of {r.daemon_from.name}"
    elif r.batch:
        mode += f", gather {r.gather_ms:g} ms"
    p, s = r.publish, r.receipt
    flags = " / ".join(f"{100 * r.flagged.get(f, 0.0):.2f}" for f in OOD_FLAGS)
    return (
        f"| {r.pairs} | {mode} | {r.rate:.1f} | {p['p50']:.1f} / {p['p99']:.1f} "
        f"| {s['p50']:.1f} / {s['p99']:.1f} | {r.frames_per_call:.1f} | {r.cpu:.0f} "
        f"| {r.cpu_per_pair:.2f} "
        f"| {r.model_per_pair:.2f} | {r.ratio:.1f}x | {r.rss:.0f} | {r.bench_cpu:.0f} "
        f"| {flags} | {r.load:.1f} |"
    )


PEAKS_HEADER = (
    "| pairs | processes | on | peak RSS MiB (all processes) | peak threads (all processes) "
    "| peak open descriptors (largest process) |"
)


def peaks_row(r: Row) -> str:
    p = r.peaks
    on = "MQTT only" if not r.everything else "control" if r.processes > 1 else "control, outputs"
    return f"| {r.pairs} | {r.processes} | {on} | {p.rss_mib:.0f} | {p.threads} | {p.fds} |"


def model_lines(ms: dict[int, float]) -> list[str]:
    """The model floor: CPU per frame and % of a core per pair, per batch size."""
    lines = ["| frames per model call | model CPU ms per frame | % of a core per pair at 16 Hz |"]
    lines.append("|---|---|---|")
    lines += [f"| {b} | {v:.3f} | {core_share_per_pair(v):.2f} |" for b, v in sorted(ms.items())]
    return lines
