"""Fault soak: a real daemon, a real mosquitto, the board emulator, and faults, many times.

    python -m scotti.daemon.tools.faults --unplugs 100 --broker-restarts 20 --silent-foot 10

Runs ``scotti-daemon`` as a subprocess reading the board emulator's pty and
publishing to a mosquitto of its own, subscribes to the daemon's topics, and
injects, one after another:

- ``unplug``: the receiver's pty goes away for ``--unplug-seconds``, then comes back;
- ``broker``: mosquitto is killed, and started again after ``--broker-down-seconds``;
- ``silent foot``: the right insole's packets stop for ``--silent-seconds``.

For each fault it waits for the daemon to notice (the status reason), ends the
fault, and waits for recovery: status ``online`` again and a prediction that
arrived after the fault ended, then for the publisher to have caught up (a
health report with nothing queued) before the next fault. It prints one row
per fault and a summary:
recovered, time to recover (fault ended -> first prediction), predictions lost
(seqs missing among the predictions received; after an unplug the T-1 frames
the window needs to warm up again are not predictions and are not counted),
poses that arrived after "receiver disconnected" was published (must be 0),
and the daemon's log lines at WARNING and at ERROR (or tracebacks) while it
lasted. Exit status 0 when every fault recovered with no ERROR line.

Timings depend on the machine's load; ``--speed`` plays the board faster
(the in-suite run uses 2, to halve the window's warm-up).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

from scotti.daemon.input.board_emulator import BoardEmulator
from scotti.daemon.settings import ConfigError, default_model_path
from scotti.daemon.tools import plain_help
from scotti.daemon.tools.fault_watch import Watcher
from scotti.daemon.tools.generated import GeneratedBoard
from scotti.daemon.tools.local_broker import BrokerError, Mosquitto
from scotti.firmware_protocol.framing import decode_all
from scotti.models.contract import WINDOW

DEVICE: Final = "faults"
WARMUP_GAP: Final = WINDOW - 1  # seqs without a prediction while the window fills again
SECONDS_PER: Final = {"unplug": 6.0, "broker": 4.0}  # a generous guess, to size the records


@dataclass
class Plan:
    unplugs: int = 10
    broker_restarts: int = 10
    silent_feet: int = 10
    unplug_s: float = 0.5
    broker_down_s: float = 0.5
    silent_s: float = 10.0
    speed: float = 1.0
    timeout_s: float = 30.0  # per fault, to notice and to recover
    model: Path | None = None
    log: Path | None = None  # the daemon's log (default: a temporary file)

    @property
    def seconds(self) -> float:
        return (
            30
            + self.unplugs * (SECONDS_PER["unplug"] + self.unplug_s)
            + self.broker_restarts * (SECONDS_PER["broker"] + self.broker_down_s)
            + self.silent_feet * (self.silent_s + 4)
        )


@dataclass
class FaultResult:
    kind: str
    index: int
    noticed: bool
    recovered: bool
    recover_s: float | None  # fault ended -> first prediction after it
    lost: int  # predictions missing (seq gaps), warm-up after an unplug excepted
    after_disconnect: int  # poses that arrived after "receiver disconnected", before replug
    during: int  # poses that arrived while the fault lasted
    warnings: int  # daemon log lines at WARNING while the fault lasted
    errors: int  # daemon log lines at ERROR or CRITICAL, and tracebacks


class FaultSoak:
    def __init__(self, plan: Plan, workdir: Path) -> None:
        self.plan = plan
        self.workdir = workdir
        self.log_path = plan.log or workdir / "daemon.log"
        self.broker = Mosquitto()
        frames = round(plan.seconds * 16 * plan.speed)
        self.board = BoardEmulator(
            GeneratedBoard().records(frames), workdir / "ttyFAULTS", speed=plan.speed, loop=True
        )
        self.watch = Watcher(self.broker, f"scotti/{DEVICE}/#")
        self.results: list[FaultResult] = []
        self._proc: asyncio.subprocess.Process | None = None
        self._log_offset = 0

    # --- life --------------------------------------------------------------------------------
    async def run(self) -> list[FaultResult]:
        await asyncio.to_thread(self.broker.start)
        self.board.start()
        watcher = asyncio.create_task(self.watch.run())
        try:
            await self.watch.wait_connected(10)
            await self._start_daemon()
            await self.watch.until(lambda: self.watch.online_since(0.0), 60, "daemon online")
            self.watch.forget_before(time.monotonic())  # the start's statuses are no fault's
            for i in range(self.plan.unplugs):
                await self._fault("unplug", i, self._unplug)
            for i in range(self.plan.broker_restarts):
                await self._fault("broker", i, self._broker_restart)
            for i in range(self.plan.silent_feet):
                await self._fault("silent foot", i, self._silent_foot)
        finally:
            await self._stop_daemon()
            watcher.cancel()
            await asyncio.gather(watcher, return_exceptions=True)
            self.board.stop()
            self.broker.close()
        return self.results

    async def _start_daemon(self) -> None:
        model = self.plan.model or default_model_path()
        env = {k: v for k, v in os.environ.items() if not k.startswith("SCOTTI_")}
        env.pop("NOTIFY_SOCKET", None)
        env |= {"SCOTTI_MQTT_HEALTH_INTERVAL_S": "0.3", "SCOTTI_MQTT_RECONNECT_MAX_S": "0.5"}
        args = [
            "-m",
            "scotti.daemon.service.main",
            "--port",
            str(self.board.link),
            "--model",
            str(model),
        ]
        args += ["--broker", self.broker.url, "--device-id", DEVICE]
        with self.log_path.open("wb") as log:
            self._proc = await asyncio.create_subprocess_exec(
                sys.executable, *args, stdout=log, stderr=log, env=env
            )

    async def _stop_daemon(self) -> None:
        proc = self._proc
        if proc is None or proc.returncode is not None:
            return
        proc.terminate()
        try:
            async with asyncio.timeout(15):
                await proc.wait()
        except TimeoutError:
            proc.kill()
            await proc.wait()

    # --- one fault ---------------------------------------------------------------------------
    async def _fault(self, kind: str, index: int, inject: Callable[[], Any]) -> None:
        self._log_offset = self.log_path.stat().st_size
        began = time.monotonic()
        noticed, ended, after_disconnect = await inject()
        during = len([m for m in self.watch.messages if m.name == "pose" and began <= m.at < ended])
        recovered = False
        with contextlib.suppress(TimeoutError):
            await self.watch.until(
                lambda: self.watch.online_since(ended) and self.watch.pose_since(ended),
                self.plan.timeout_s,
                f"{kind} {index}: recovery",
            )
            recovered = True
            # Caught up before the next fault: a health report, made after recovery, with
            # no prediction waiting to be published (else the next fault would cut the
            # backlog of this one and its losses would be counted twice).
            recovered_at = time.monotonic()
            with contextlib.suppress(TimeoutError):
                await self.watch.until(
                    lambda: self.watch.drained_since(recovered_at), 10, "publisher caught up"
                )
        first = self.watch.first_pose_since(ended)
        warnings, errors = self._log_levels()
        gaps = self.watch.missing_seqs()
        lost = max(0, gaps - WARMUP_GAP) if kind == "unplug" else gaps
        self.results.append(
            FaultResult(
                kind, index, noticed, recovered, None if first is None else first - ended,
                lost, after_disconnect, during, warnings, errors,
            )
        )  # fmt: skip
        print(row(self.results[-1]), flush=True)
        self.watch.forget_before(time.monotonic())

    async def _unplug(self) -> tuple[bool, float, int]:
        await asyncio.to_thread(self.board.unplug)
        noticed = await self._notice(lambda: self.watch.reason_since("receiver disconnected"))
        await asyncio.sleep(self.plan.unplug_s)
        poses_after = self.watch.poses_after_disconnect()
        await asyncio.to_thread(self.board.replug)
        return noticed, time.monotonic(), poses_after

    async def _broker_restart(self) -> tuple[bool, float, int]:
        await asyncio.to_thread(self.broker.stop)
        await asyncio.sleep(self.plan.broker_down_s)
        await asyncio.to_thread(self.broker.start)
        return True, time.monotonic(), 0

    async def _silent_foot(self) -> tuple[bool, float, int]:
        began = time.monotonic()
        self.board.line = _without_right_foot
        noticed = await self._notice(lambda: self.watch.reason_since("right insole silent"))
        await asyncio.sleep(max(0.0, self.plan.silent_s - (time.monotonic() - began)))
        self.board.line = None
        return noticed, time.monotonic(), 0

    async def _notice(self, seen: Callable[[], bool]) -> bool:
        try:
            await self.watch.until(seen, self.plan.timeout_s, "the fault noticed")
        except TimeoutError:
            return False
        return True

    def _log_levels(self) -> tuple[int, int]:
        with self.log_path.open("rb") as f:
            f.seek(self._log_offset)
            lines = f.read().decode(errors="replace").splitlines()
        warnings = sum(line.startswith("WARNING") for line in lines)
        errors = sum(line.startswith(("ERROR", "CRITICAL", "Traceback")) for line in lines)
        return warnings, errors


def _without_right_foot(data: bytes) -> bytes | None:
    packets, _ = decode_all(data)
    return None if packets and getattr(packets[0], "foot", None) == 1 else data


# --- the table ------------------------------------------------------------------------------
HEADER: Final = (
    f"{'fault':<12} {'#':>3} {'noticed':>7} {'recovered':>9} {'recover s':>9} "
    f"{'lost':>4} {'late':>4} {'WARN':>4} {'ERROR':>5}"
)


def row(r: FaultResult) -> str:
    recover = "-" if r.recover_s is None else f"{r.recover_s:.2f}"
    return (
        f"{r.kind:<12} {r.index + 1:>3} {_yes(r.noticed):>7} {_yes(r.recovered):>9} "
        f"{recover:>9} {r.lost:>4} {r.after_disconnect:>4} {r.warnings:>4} {r.errors:>5}"
    )


def _yes(flag: bool) -> str:
    return "yes" if flag else "NO"


def summary(results: list[FaultResult]) -> str:
    lines = [
        "| fault | injected | recovered | recover s median | recover s max | predictions lost "
        "| poses after disconnect | WARNING lines | ERROR lines |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for kind in dict.fromkeys(r.kind for r in results):
        rs = [r for r in results if r.kind == kind]
        times = [r.recover_s for r in rs if r.recover_s is not None]
        median = f"{statistics.median(times):.2f}" if times else "-"
        worst = f"{max(times):.2f}" if times else "-"
        lines.append(
            f"| {kind} | {len(rs)} | {sum(r.recovered for r in rs)} | {median} | {worst} | "
            f"{sum(r.lost for r in rs)} | {sum(r.after_disconnect for r in rs)} | "
            f"{sum(r.warnings for r in rs)} | {sum(r.errors for r in rs)} |"
        )
    return "\n".join(lines)


def passed(results: list[FaultResult]) -> bool:
    return all(r.noticed and r.recovered and not r.errors for r in results)


async def soak(plan: Plan) -> list[FaultResult]:
    with tempfile.TemporaryDirectory(prefix="scotti-faults-") as tmp:
        return await FaultSoak(plan, Path(tmp)).run()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m scotti.daemon.tools.faults", description=plain_help(__doc__)
    )
    p.add_argument("--unplugs", type=int, default=10)
    p.add_argument("--broker-restarts", type=int, default=10)
    p.add_argument("--silent-foot", type=int, default=10, help="silent-foot faults")
    p.add_argument("--unplug-seconds", type=float, default=0.5)
    p.add_argument("--broker-down-seconds", type=float, default=0.5)
    p.add_argument("--silent-seconds", type=float, default=10.0)
    p.add_argument("--speed", type=float, default=1.0, help="board playback rate")
    p.add_argument("--model", type=Path, help="ONNX step graph (default: the shipped one)")
    p.add_argument("--log", type=Path, help="keep the daemon's log here")
    args = p.parse_args(argv)
    plan = Plan(
        unplugs=args.unplugs,
        broker_restarts=args.broker_restarts,
        silent_feet=args.silent_foot,
        unplug_s=args.unplug_seconds,
        broker_down_s=args.broker_down_seconds,
        silent_s=args.silent_seconds,
        speed=args.speed,
        model=args.model,
        log=args.log,
    )
    print(HEADER, flush=True)
    started = time.monotonic()
    try:
        results = asyncio.run(soak(plan))
    except (BrokerError, ConfigError) as exc:
        print(f"faults: {exc}", file=sys.stderr)
        return 78
    print(f"\n{summary(results)}\n\n{len(results)} faults in {time.monotonic() - started:.0f} s")
    return 0 if passed(results) else 1


if __name__ == "__main__":
    sys.exit(main())
