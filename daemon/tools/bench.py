"""Benchmark: one daemon serving N insole pairs at 16 Hz against a real mosquitto.

For each N in ``--pairs``, N receiver boards play simulated people's insole
frames (both feet, row blocks as the radio sends them; ``bench_boards``) into N
pseudo-terminals from a helper process, and one ``scotti-daemon`` subprocess
reads them all through a ``[[devices]]`` config. A subscriber in this process
takes every pose and measures what a consumer sees: receipt time minus the
frame's last byte (``predicted_for_mono_ns`` - 1/16 s, the same host clock), and
the share of poses flagged out_of_range, unloaded or unfamiliar (near zero for
these frames: a pose flagged costs the daemon a slower path). The daemon's own
``latency_ms`` (last byte -> publish) comes from the payload. The daemon's CPU
(100 % = one core) and peak RSS are sampled with psutil (the ``[bench]`` extra:
``pip install 'scotti[bench]'``), and from the daemon's start to the end of the
run its peak memory, threads and open descriptors, from which the unit's
MemoryMax, TasksMax and LimitNOFILE are set (docs/deploy.md).

Beside the daemon, the model's floor: its step's own CPU per frame at the batch
the engine can form (``bench_model``), as % of a core per pair, and the daemon's
CPU per pair over it (issue 42's goal: at most 1.5x). The bench's own CPU (the
boards, the subscriber, mosquitto) is printed apart: on a 2-core host it is
taken from the daemon. ``--profile`` samples the daemon with py-spy for the
measured seconds and prints its CPU by part of the path (``bench_profile``).

Each N runs with the batched engine (``inference.batch = true``) and, with
``--modes``, one model call per pair (``false``), and with ``--processes`` over
several worker processes (daemon/service/processes.py). A measurement, never a test.

    python -m scotti.daemon.tools.bench --pairs 1 8 32 64 96 128 --processes 1 2 --modes batch
    python -m scotti.daemon.tools.bench --pairs 32 --modes batch --seconds 20 --profile
    python -m scotti.daemon.tools.bench --step-batches 1 2 4 8 16 32 64   # the model alone
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import subprocess
import sys
import tempfile
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from scotti.daemon.service.counters import latency_summary
from scotti.daemon.settings import ConfigError, default_model_path
from scotti.daemon.tools.bench_boards import PERIOD_NS, board_records, play_boards, render_people
from scotti.daemon.tools.bench_model import engine_batch, model_cpu_ms
from scotti.daemon.tools.bench_subscriber import (
    Poses,
    PoseSubscriber,
    collect,
    engine_frames_per_call,
)
from scotti.daemon.tools.bench_table import (
    COLUMNS,
    GOAL_P99_MS,
    GOAL_RATIO,
    HEADER,
    PEAKS_HEADER,
    Row,
    model_lines,
    peaks_row,
    percentiles,
    table_row,
)
from scotti.daemon.tools.local_broker import Mosquitto
from scotti.models.contract import FRAME_RATE_HZ

if TYPE_CHECKING:
    from scotti.daemon.tools.bench_profile import Profile

# Kept importable from here: the tests', the control flood's and the web bench's boards.
_play_boards = play_boards
__all__ = ["PERIOD_NS", "board_records", "collect", "config_text", "main", "percentiles"]


def config_text(
    links: list[Path],
    broker: Mosquitto,
    batch: bool,
    max_batch: int = 8,
    processes: int = 1,
    *,
    everything: bool = False,
    gather_ms: float | None = 0.0,
) -> str:
    """``everything``: remote control on and, in one process, the web and Foxglove
    servers on free ports (no clients), so that the peaks hold all the daemon opens."""
    tables = "".join(
        f'\n[[devices]]\nid = "pair{i:02d}"\nport = "{link}"\n' for i, link in enumerate(links)
    )
    control = "control = true\n" if everything else ""
    outputs = "[outputs]\nweb = 0\nfoxglove = 0\n" if everything and processes == 1 else ""
    # gather_ms None: the key left out, for a daemon from before the setting (--daemon-from).
    gather = f"gather_ms = {gather_ms}\n" if gather_ms is not None else ""
    return (
        f'log_level = "warning"\nprocesses = {processes}\n'
        f"[inference]\nbatch = {str(batch).lower()}\nmax_batch = {max_batch}\n{gather}"
        # Health at its default interval (5 s): a shorter one costs the daemon CPU the
        # bench would count (64 devices at 1 s: a tenth of its event loop).
        f'[mqtt]\nbroker = "{broker.url}"\n{control}{outputs}{tables}'
    )


def run_one(
    broker: Mosquitto,
    model: Path,
    pairs: int,
    batch: bool,
    seconds: float,
    warmup: float,
    max_batch: int = 8,
    processes: int = 1,
    everything: bool = False,
    *,
    model_ms: float = 0.0,
    profile: bool = False,
    people: list[np.ndarray] | None = None,
    gather_ms: float | None = 0.0,
    daemon_from: Path | None = None,
) -> Row:
    from scotti.daemon.tools.bench_process import Peaks, sample_process

    folder = Path(tempfile.mkdtemp(prefix="scotti-bench-"))
    links = [folder / f"tty{i:02d}" for i in range(pairs)]
    config = folder / "devices.toml"
    text = config_text(
        links, broker, batch, max_batch, processes, everything=everything, gather_ms=gather_ms
    )
    config.write_text(text)
    ctx = multiprocessing.get_context("spawn")
    ready, stop, dropped = ctx.Event(), ctx.Event(), ctx.Value("q", 0)
    boards = ctx.Process(
        target=play_boards,
        args=([str(p) for p in links], 0.0, ready, stop, dropped, people),
        daemon=True,
    )
    boards.start()
    if not ready.wait(120):
        boards.kill()
        msg = "the emulated boards did not start"
        raise RuntimeError(msg)
    cmd = [sys.executable, "-m", "scotti.daemon.service.main", "--config", str(config)]
    cmd += ["--model", str(model)]
    env = {k: v for k, v in os.environ.items() if not k.startswith("SCOTTI_")}
    if daemon_from is not None:  # ``scotti`` is a namespace package: a link to a checkout is it
        (folder / "scotti").symlink_to(daemon_from.resolve())
        env["PYTHONPATH"] = str(folder)
    daemon = subprocess.Popen(cmd, env=env)
    measuring, peaks = threading.Event(), Peaks()
    others = (boards.pid or 0, os.getpid(), *_broker_pid(broker))
    try:
        with ThreadPoolExecutor(2) as pool:
            usage = pool.submit(sample_process, daemon.pid, seconds, measuring, others, peaks)
            dropped_before = pool.submit(_once_set, measuring, lambda: int(dropped.value))
            spy = _profile(daemon.pid, seconds, measuring, folder) if profile else None
            poses = PoseSubscriber(broker, seconds, warmup, pairs=pairs, measuring=measuring).run()
            drops = int(dropped.value) - dropped_before.result()
            report = spy.report() if spy is not None else ""
            cpu_rss_bench = usage.result()
    finally:
        daemon.terminate()
        daemon.wait(30)
        stop.set()
        boards.join(15)
    # The devices' last health (retained, published as the daemon stops): the whole run's.
    per_call = engine_frames_per_call(broker, pairs)
    return _row(
        poses, pairs, batch, processes, seconds, cpu_rss_bench, peaks, everything,
        model_ms=model_ms, dropped=drops, profile=report, frames_per_call=per_call,
        gather_ms=gather_ms or 0.0, daemon_from=daemon_from,
    )  # fmt: skip


def _once_set(event: threading.Event, read: Callable[[], int]) -> int:
    """``read()`` as soon as ``event`` is set (the measured seconds start)."""
    event.wait()
    return read()


def _profile(pid: int, seconds: float, measuring: threading.Event, folder: Path) -> Profile:
    from scotti.daemon.tools.bench_profile import Profile

    return Profile(pid, seconds, measuring, folder / "py-spy.txt")


def _row(
    poses: Poses,
    pairs: int,
    batch: bool,
    processes: int,
    seconds: float,
    usage: tuple[float, float, float],
    peaks: object,
    everything: bool,
    **rest: object,
) -> Row:
    cpu, rss, bench_cpu = usage
    return Row(
        pairs=pairs,
        batch=batch,
        processes=processes,
        published=len(poses),
        seconds=seconds,
        publish=latency_summary(poses.publish),
        receipt=latency_summary(poses.receipt),
        cpu=cpu,
        rss=rss,
        bench_cpu=bench_cpu,
        load=os.getloadavg()[0],
        peaks=peaks,  # type: ignore[arg-type]
        everything=everything,
        flagged=poses.shares(),
        **rest,  # type: ignore[arg-type]
    )


def _broker_pid(broker: Mosquitto) -> tuple[int, ...]:
    proc = getattr(broker, "_proc", None)  # the local broker keeps its Popen private
    return (proc.pid,) if isinstance(proc, subprocess.Popen) else ()


def run(args: argparse.Namespace, model: Path) -> int:
    modes = [m == "batch" for m in args.modes]
    sizes = {engine_batch(n, b, args.max_batch) for n in args.pairs for b in modes}
    print(
        f"scotti-daemon bench: {args.seconds:.0f} s measured {args.warmup:.0f} s after every "
        f"pair's first pose, {FRAME_RATE_HZ:.0f} Hz per pair (simulated people), model "
        f"{model.name}, max_batch {args.max_batch}, {os.cpu_count()} CPUs, load average "
        f"{os.getloadavg()[0]:.1f} at start, nice {os.nice(0)}",
        flush=True,
    )
    # A quarter of a run's measured seconds at most: a short run stays short.
    model_ms = model_cpu_ms(model, sorted(sizes), min(1.5, args.seconds / 4))
    people = render_people(max(args.pairs))  # once for every run
    print("\nThe model's step alone (its floor; CPU time, one onnxruntime thread):")
    print("\n".join(model_lines(model_ms)))
    print(
        f"\nmodel per pair: the model alone at the batch the engine can form (min(pairs, "
        f"max_batch)); daemon / model: the daemon's CPU per pair over it (goal <= "
        f"{GOAL_RATIO}x); subscriber p99 goal < {GOAL_P99_MS:.1f} ms; flagged: share of "
        f"the poses with each flag\n",
        flush=True,
    )
    print(HEADER)
    print("|" + "---|" * COLUMNS, flush=True)
    rows = []
    with Mosquitto() as broker:
        for pairs in args.pairs:
            for processes in args.processes:
                for batch, gather_ms, daemon_from in _engine_modes(
                    modes, args.gather_ms, args.daemon_from
                ):
                    row = run_one(
                        broker, model, pairs, batch, args.seconds, args.warmup,
                        args.max_batch, processes, args.everything,
                        model_ms=model_ms[engine_batch(pairs, batch, args.max_batch)],
                        profile=args.profile, people=people[:pairs], gather_ms=gather_ms,
                        daemon_from=daemon_from,
                    )  # fmt: skip
                    rows.append(row)
                    print(table_row(row), flush=True)
                    if row.dropped:
                        print(f"  ({row.dropped} foot frames not taken from the ports in time)")
                    if row.profile:
                        print(row.profile, flush=True)
    print("\nFrom the daemon's start to the end of each run (docs/deploy.md, the unit's limits):")
    print(PEAKS_HEADER)
    print("|" + "---|" * 6)
    for row in rows:
        print(peaks_row(row))
    return 0 if all(r.published for r in rows) else 1


def _engine_modes(
    modes: list[bool], gathers: list[float], daemon_from: Path | None
) -> list[tuple[bool, float | None, Path | None]]:
    """(batch, gather_ms, checkout) per run: each gather for the batched engine, none per
    pair; with ``daemon_from``, first that checkout's daemon (its own defaults) then this."""
    runs: list[tuple[bool, float | None, Path | None]] = []
    if daemon_from is not None:
        runs += [(b, None, daemon_from) for b in modes]
    runs += [(b, g, None) for b in modes for g in (gathers if b else [0.0])]
    return runs


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m scotti.daemon.tools.bench")
    p.add_argument("--pairs", type=int, nargs="+", default=[1], help="insole pairs, e.g. 1 8 32")
    p.add_argument("--seconds", type=float, default=20.0, help="measured seconds per run")
    p.add_argument(
        "--warmup", type=float, default=3.0,
        help="seconds from every pair's first pose to the measurement",
    )  # fmt: skip
    p.add_argument(
        "--modes", nargs="+", choices=("batch", "single"), default=["batch", "single"],
        help="batched engine (batch) and/or one model call per pair (single)",
    )  # fmt: skip
    p.add_argument("--max-batch", type=int, default=8, help="inference.max_batch (default 8)")
    p.add_argument(
        "--gather-ms", type=float, nargs="+", default=[4.0], metavar="MS",
        help="inference.gather_ms, one run each (default 4, the daemon's default)",
    )  # fmt: skip
    p.add_argument(
        "--processes", type=int, nargs="+", default=[1], metavar="N",
        help="the daemon's worker processes, one run each (default 1: all pairs in one)",
    )  # fmt: skip
    p.add_argument(
        "--everything", action="store_true",
        help="also remote control and (with one process) the web and Foxglove servers, "
        "idle: the peaks a unit's limits must allow (docs/deploy.md)",
    )  # fmt: skip
    p.add_argument(
        "--profile", action="store_true",
        help="also sample the daemon with py-spy for the measured seconds and print its "
        "CPU by part of the path",
    )  # fmt: skip
    p.add_argument(
        "--daemon-from", type=Path, metavar="CHECKOUT",
        help="also run the daemon of another checkout of this repository (e.g. a `git "
        "worktree` of an older commit) before this one's, same boards and subscriber: "
        "a before/after in one run",
    )  # fmt: skip
    p.add_argument("--model", type=Path, help="ONNX step graph (default: the shipped one)")
    p.add_argument(
        "--step-batches", type=int, nargs="+", metavar="B",
        help="instead: time the model's step alone at these batch sizes (no daemon, no broker)",
    )  # fmt: skip
    args = p.parse_args(argv)
    if not args.step_batches and (why := _missing_tools(args.profile)):
        print(f"bench: {why}", file=sys.stderr)
        return 1
    if (
        min(args.pairs) < 1
        or min(args.processes) < 1
        or args.seconds <= 0
        or args.warmup < 0
        or args.max_batch < 1
        or min(args.gather_ms) < 0
    ):
        print(
            "bench: --pairs, --processes and --max-batch must be >= 1, --seconds > 0, "
            "--warmup and --gather-ms >= 0",
            file=sys.stderr,
        )
        return 2
    try:
        model = args.model or default_model_path()
    except ConfigError as exc:
        print(f"bench: {exc}", file=sys.stderr)
        return 78
    if args.step_batches:
        if min(args.step_batches) < 1:
            print("bench: --step-batches must be >= 1", file=sys.stderr)
            return 2
        from scotti.daemon.tools.step_costs import step_costs

        return step_costs(model, args.step_batches)
    return run(args, model)


def _missing_tools(profile: bool) -> str:
    """What the bench needs and this host lacks, in one line ("" when nothing)."""
    try:
        import psutil  # noqa: F401
    except ImportError:
        return "needs psutil: pip install 'scotti[bench]'"
    if profile:
        from scotti.daemon.tools.bench_profile import spy_path

        try:
            spy_path()
        except FileNotFoundError as exc:
            return str(exc)
    return ""


if __name__ == "__main__":
    sys.exit(main())
