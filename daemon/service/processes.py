"""Many insole pairs over several processes: ``processes = N`` in the config.

One process runs every device's reading, decoding, assembly and publishing on
one event loop, and Python runs one thread of it at a time. On the 2-core
host that thread is the limit past about 96 pairs (docs/performance.md: 128
pairs need two processes there). With ``processes = N``
the daemon starts N worker processes instead, each a whole daemon
(``app.Daemon``) over its share of the ``[[devices]]``: every N-th device, so
receivers listed in order spread evenly. Each worker has its own event loop,
model and inference engine (batching its own devices' frames), and one MQTT
client per device: topics, messages and recordings are those of the
one-process daemon, and a subscriber cannot tell the difference.

This process, the supervisor, holds no model and reads no port. It
- starts the workers and restarts one that dies (a crash, the OOM killer)
  after a capped backoff; meanwhile the broker publishes its devices' last
  wills (``offline``), and the other workers go on untouched;
- stops everything when a worker exits with EX_CONFIG (the model does not
  load: starting it again would fail the same way);
- on SIGTERM or SIGINT, passes SIGTERM on; each worker stops gracefully
  (``offline``, queues drained, recordings closed); the exit status is the
  worst of theirs;
- talks to systemd: READY once the workers are started, STATUS with how many
  run, the watchdog patted while it supervises (a worker wedged but alive is
  not seen; its devices' ``health`` stops, which subscribers do see).

The outputs (web view, Foxglove, MCAP, LSL) are one server or file for all
devices of one process; they need ``processes = 1`` (settings say so).
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import multiprocessing.connection
import os
import signal
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from multiprocessing.process import BaseProcess
from pathlib import Path
from types import FrameType
from typing import Final

from scotti.daemon.service.notify import Notifier
from scotti.daemon.settings import EX_CONFIG, DeviceSettings, Settings
from scotti.daemon.waiting import Backoff

log = logging.getLogger(__name__)

# A worker that ran this long before it died starts again after the shortest delay.
STEADY_S: Final = 60.0
# Between two looks at the workers: a died one is noticed within this.
POLL_S: Final = 0.5
# A worker still alive this long after the stop budget and a SIGTERM is killed.
KILL_GRACE_S: Final = 3.0
# systemd's own variables: only the supervisor talks to it.
_SYSTEMD_ENV: Final = ("NOTIFY_SOCKET", "WATCHDOG_USEC", "WATCHDOG_PID")


def share_devices(
    devices: Sequence[DeviceSettings], processes: int
) -> list[tuple[DeviceSettings, ...]]:
    """Every ``processes``-th device to each worker (no worker without a device)."""
    count = max(1, min(processes, len(devices)))
    return [tuple(devices[i::count]) for i in range(count)]


def worker_settings(settings: Settings, devices: tuple[DeviceSettings, ...]) -> Settings:
    """One worker's settings: the same, with its devices only and one process.

    Built from the validated values (``model_construct``), not validated again:
    a worker would otherwise read the environment and the config file anew. And
    of the base class, which pickles (``load_settings`` makes a subclass per file).
    """
    values = {name: getattr(settings, name) for name in Settings.model_fields}
    values |= {"source": None, "devices": devices, "processes": 1}
    return Settings.model_construct(**values)


def run_worker(settings: Settings, model_path: Path, index: int) -> None:
    """A worker process's body: one ``Daemon`` over its devices; exits with its status."""
    for name in _SYSTEMD_ENV:
        os.environ.pop(name, None)
    from scotti.daemon.service.main import PROG, configure_logging

    configure_logging(settings.log_level, prefix=f"worker {index}: ")
    import asyncio

    from scotti.daemon.errors import DaemonError
    from scotti.daemon.service.app import Daemon
    from scotti.models.errors import ModelError
    from scotti.models.kv_streaming import open_step_model

    try:
        runtime = open_step_model(model_path, threads=settings.model.threads)
    except ModelError as exc:
        print(f"{PROG}: model error: {exc}", file=sys.stderr)
        sys.exit(EX_CONFIG)
    try:
        code = asyncio.run(Daemon(settings, runtime, Notifier({})).run())
    except DaemonError as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        code = EX_CONFIG
    except KeyboardInterrupt:
        code = 130
    sys.exit(code)


@dataclass
class _Worker:
    index: int
    settings: Settings
    process: BaseProcess | None = None
    started_mono: float = 0.0
    restart_at: float | None = None  # when to start again after it died
    backoff: Backoff = field(default_factory=lambda: Backoff(initial_s=0.5, cap_s=30.0))
    exit_code: int | None = None  # set once it ended for good

    @property
    def names(self) -> str:
        return ", ".join(d.id for d in self.settings.devices)


class Supervisor:
    """Starts the workers, restarts the ones that die, stops them all on a signal."""

    def __init__(
        self,
        settings: Settings,
        model_path: Path,
        notifier: Notifier | None = None,
    ) -> None:
        self.settings = settings
        self.model_path = model_path
        self.notifier = notifier or Notifier()
        self.restarts = 0  # workers started again after they died, in this run
        self._context = multiprocessing.get_context("spawn")  # no inherited threads or loop
        self._stopping = False
        self.workers = [
            _Worker(i, worker_settings(settings, share))
            for i, share in enumerate(share_devices(settings.device_list(), settings.processes))
        ]

    def run(self) -> int:
        """Until every worker has ended (replays) or a signal; the worst exit status."""
        previous = {
            sig: signal.signal(sig, self._on_signal) for sig in (signal.SIGTERM, signal.SIGINT)
        }
        try:
            for worker in self.workers:
                self._start(worker)
            self.notifier.ready(self._status())
            self._supervise()
            self.notifier.stopping()
            return self._stop_all()
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
            self.notifier.close()

    # --- the loop -----------------------------------------------------------------------

    def _supervise(self) -> None:
        pat_every = self.notifier.watchdog_interval_s
        last_pat = 0.0
        while not self._stopping:
            alive = [w.process.sentinel for w in self.workers if self._running(w) and w.process]
            if alive:
                multiprocessing.connection.wait(alive, timeout=POLL_S)  # returns as one exits
            else:
                time.sleep(POLL_S)  # all waiting for their restart
            now = time.monotonic()
            if pat_every is not None and now - last_pat >= pat_every:
                self.notifier.watchdog()
                last_pat = now
            for worker in self.workers:
                self._look_after(worker, now)
            if all(w.exit_code is not None for w in self.workers):
                return  # every replay ended, or a worker that cannot start stopped us

    def _look_after(self, worker: _Worker, now: float) -> None:
        if worker.exit_code is not None:
            return
        if worker.restart_at is not None:
            if now >= worker.restart_at and not self._stopping:
                self.restarts += 1
                self._start(worker)
                self.notifier.status(self._status())
            return
        process = worker.process
        if process is None or process.is_alive():
            return
        code = process.exitcode if process.exitcode is not None else 1
        if code == 0:
            log.info("worker %d (%s) ended", worker.index, worker.names)
            worker.exit_code = 0
        elif code == EX_CONFIG:
            log.error("worker %d (%s) cannot run: stopping", worker.index, worker.names)
            worker.exit_code = code
            self._stopping = True
        else:
            if now - worker.started_mono >= STEADY_S:
                worker.backoff.reset()
            delay = worker.backoff.next_delay()
            log.warning(
                "worker %d (%s) died (%s); starting it again in %.1f s",
                worker.index,
                worker.names,
                _describe_exit(code),
                delay,
            )
            worker.restart_at = now + delay
        self.notifier.status(self._status())

    def _start(self, worker: _Worker) -> None:
        process = self._context.Process(
            target=run_worker,
            args=(worker.settings, self.model_path, worker.index),
            name=f"scotti-worker-{worker.index}",
        )
        process.start()
        worker.process, worker.started_mono, worker.restart_at = process, time.monotonic(), None
        log.info("worker %d (pid %s): %s", worker.index, process.pid, worker.names)

    def _stop_all(self) -> int:
        running = [w for w in self.workers if self._running(w)]
        for worker in running:
            assert worker.process is not None
            with contextlib.suppress(ProcessLookupError):  # it has just exited
                os.kill(worker.process.pid or 0, signal.SIGTERM)
        # Each worker's own stop budget (as ``Daemon._stop_devices``), then a kill.
        budget = 2 * self.settings.stop_timeout_s + 1 + KILL_GRACE_S
        deadline = time.monotonic() + budget
        status = max((w.exit_code or 0 for w in self.workers), default=0)
        for worker in running:
            assert worker.process is not None
            worker.process.join(max(0.0, deadline - time.monotonic()))
            if worker.process.is_alive():
                log.warning("worker %d did not stop within %.1f s: killed", worker.index, budget)
                worker.process.kill()
                worker.process.join(5.0)
                status = max(status, 1)
                continue
            code = worker.process.exitcode
            status = max(status, code if code is not None and code >= 0 else 1)
        return status

    def _running(self, worker: _Worker) -> bool:
        return worker.exit_code is None and worker.restart_at is None and worker.process is not None

    def _on_signal(self, signum: int, _frame: FrameType | None) -> None:
        if not self._stopping:
            log.info("%s: stopping the workers", signal.Signals(signum).name)
        self._stopping = True

    def _status(self) -> str:
        up = sum(1 for w in self.workers if self._running(w) and w.process and w.process.is_alive())
        devices = len(self.settings.device_list())
        return (
            f"{up} of {len(self.workers)} worker processes running, {devices} devices, "
            f"{self.restarts} restarts"
        )


def _describe_exit(code: int) -> str:
    if code < 0:
        try:
            return f"signal {signal.Signals(-code).name}"
        except ValueError:
            return f"signal {-code}"
    return f"exit status {code}"


def supervise(settings: Settings, model_path: Path) -> int:
    """``scotti-daemon`` with ``processes`` > 1: the exit status of the whole."""
    return Supervisor(settings, model_path).run()
