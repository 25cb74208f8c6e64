"""Sessions replayed in worker processes (``scotti eval --processes N``).

Threads (``--jobs``) overlap the model's calls, but everything between them (reading
the file, decoding, assembly, pairing, the windows' bookkeeping, scoring) is Python
that holds the interpreter's lock: two threads ran one session only 1.2x as fast as
one (docs/evaluation.md, "How fast it runs"). Whole sessions in separate processes
share nothing, so an evaluation of several sessions runs on every core. Each worker
opens the same graphs (by path, threads and progress calibration) once, replays the
sessions it is given on one thread, and sends back what pooling keeps of them
(``SessionReplay.drop_predictions``): the same reports as one process gives.

Workers are spawned, not forked: the parent already holds onnxruntime sessions and
their threads, which a fork would copy mid-state.
"""

from __future__ import annotations

import multiprocessing
import resource
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path

from scotti.evaluation.errors import EvaluationError
from scotti.evaluation.replay import SessionReplay, replay_session_models, window_graphs
from scotti.firmware_protocol.pairing import PairingConfig
from scotti.models.kv_streaming import StepModel, open_step_model
from scotti.models.runtime import ScottiRuntime


@dataclass(frozen=True)
class GraphSpec:
    """How a worker opens the parent's step graph again."""

    path: Path
    threads: int
    calibrate_progress: bool

    @classmethod
    def of(cls, runtime: StepModel) -> GraphSpec:
        # A runtime applies a calibration exactly when the model has one and it was
        # switched on; opened with the same switch, the worker's gives the same progress.
        calibrated = runtime.progress_calibration is not None
        return cls(Path(runtime.path), runtime.threads, calibrated)


@dataclass(frozen=True)
class SessionDone:
    """One session's replays (a list per model, predictions dropped) and its costs."""

    replays: list[SessionReplay]
    seconds: float  # wall time in the worker
    cpu_seconds: float  # the worker's CPU time for this session


# A worker's graphs, opened once by ``_open`` (a worker process has one of each).
_runtimes: list[StepModel] = []
_windows: list[ScottiRuntime] | None = None


def _open(specs: Sequence[GraphSpec], every: int) -> None:
    global _windows
    _runtimes[:] = [
        open_step_model(s.path, threads=s.threads, calibrate_progress=s.calibrate_progress)
        for s in specs
    ]
    _windows = window_graphs(_runtimes) if every > 1 else None


def _replay(path: str, pairing: PairingConfig | None, every: int, batch: int) -> SessionDone:
    started, cpu = time.perf_counter(), time.process_time()
    replays = replay_session_models(
        path, _runtimes, pairing, every=every, windows=_windows, batch=batch, jobs=1
    )
    for replay in replays:
        replay.drop_predictions()
    return SessionDone(replays, time.perf_counter() - started, time.process_time() - cpu)


@dataclass
class ProcessReplays:
    """``replays(paths)`` in session order; ``cpu_seconds`` sums the workers' CPU time."""

    runtimes: Sequence[StepModel]
    processes: int
    pairing: PairingConfig | None = None
    every: int = 1
    batch: int = 1
    cpu_seconds: float = 0.0

    def replays(
        self,
        paths: Sequence[str | Path],
        on_session: Callable[[int, int, Path, float], None] | None = None,
    ) -> Iterator[list[SessionReplay]]:
        specs = [GraphSpec.of(r) for r in self.runtimes]
        context = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(
            min(self.processes, max(len(paths), 1)),
            mp_context=context,
            initializer=_open,
            initargs=(specs, self.every),
        ) as pool:
            futures: list[Future[SessionDone]] = [
                pool.submit(_replay, str(p), self.pairing, self.every, self.batch) for p in paths
            ]
            try:
                for i, (p, future) in enumerate(zip(paths, futures, strict=True)):
                    try:
                        done = future.result()
                    except BrokenProcessPool:
                        # A worker that could not open the graphs, or died (memory): say
                        # so in one line; the worker's own error went to stderr.
                        msg = (
                            f"a worker process ended while replaying {Path(p).name}: it could "
                            "not open the model, or was killed (out of memory?); "
                            "--processes 1 replays in this process"
                        )
                        raise EvaluationError(msg) from None
                    self.cpu_seconds += done.cpu_seconds
                    if on_session is not None:
                        on_session(i + 1, len(paths), Path(p), done.seconds)
                    yield done.replays
            finally:
                for future in futures:  # a session that failed: the ones after it never start
                    future.cancel()


def peak_rss_children_mb() -> int:
    """The largest worker's peak RSS so far (those that have ended), MB."""
    return round(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024)  # Linux: kB
