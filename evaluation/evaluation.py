"""Evaluate a model the way the daemon runs it: labelled session files replayed
through the live path (``replay``), each prediction scored against the label of
its time (``frames``), pooled and scored the paper's way (``scores``).

No torch, no asyncio: ``scotti eval`` and the experiment drivers use it.
"""

from __future__ import annotations

import queue
import resource
import time
from collections import Counter
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from scotti.evaluation.decoded import DecodeWorker
from scotti.evaluation.errors import EvaluationError
from scotti.evaluation.frames import FrameScores, FrameSet
from scotti.evaluation.processes import ProcessReplays, peak_rss_children_mb
from scotti.evaluation.replay import (
    SessionReplay,
    replay_session,
    replay_session_models,
    window_graphs,
)
from scotti.evaluation.sampling import window_timing
from scotti.evaluation.scores import random_baseline, score, task_metrics
from scotti.evaluation.segments import BATCH, quick_gil_handoff
from scotti.firmware_protocol.pairing import PairingConfig
from scotti.models.kv_streaming import StepModel
from scotti.models.ood import shares_of
from scotti.models.runtime import ScottiRuntime

# Sessions replayed at once when segments are stepped on threads (``evaluate_models``).
SESSIONS_IN_FLIGHT = 2
DECODE_CHOICES = ("auto", "here", "process")
# Session bytes from which ``--decode auto`` decodes in a process: about 18,000 pairs,
# whose decoding (89-107 us a pair, the report's rate.decode_cpu_seconds) outweighs the
# worker's start and the pipeline's filling (its first 8,192 pairs) several times.
AUTO_DECODE_BYTES = 64 << 20

__all__ = [
    "EvaluationError",
    "FrameScores",
    "FrameSet",
    "SessionReplay",
    "evaluate_models",
    "evaluate_sessions",
    "random_baseline",
    "replay_session",
    "replay_session_models",
    "score",
    "task_metrics",
]


def evaluate_sessions(
    paths: Sequence[str | Path],
    runtime: StepModel,
    pairing: PairingConfig | None = None,
    *,
    every: int = 1,
    batch: int = BATCH,
    jobs: int = 1,
) -> dict[str, Any]:
    """Replay every session, pool their frames, and score them (JSON-ready)."""
    return evaluate_models(paths, [runtime], pairing, every=every, batch=batch, jobs=jobs)[0]


def evaluate_models(
    paths: Sequence[str | Path],
    runtimes: Sequence[StepModel],
    pairing: PairingConfig | None = None,
    *,
    every: int = 1,
    batch: int = BATCH,
    jobs: int = 1,
    processes: int = 1,
    decode: str = "auto",
    on_session: Callable[[int, int, Path, float], None] | None = None,
) -> list[dict[str, Any]]:
    """``evaluate_sessions`` for several models over one replay of each session.

    ``jobs`` > 1: each session's segments stepped in that many groups side by side,
    on threads (``replay_session_models``), two sessions replayed at a time; the
    reports are the same as with one thread, sessions in the order given.
    ``processes`` > 1: whole sessions in that many worker processes instead, each on
    one thread (``evaluation.processes``; ``jobs`` is not used), the same reports.
    The workers are spawned and import the main module: a script that calls this
    with ``processes`` > 1 keeps its work under ``if __name__ == "__main__":``.
    ``decode``: where each session is read and decoded (``decode_where``): ``here``,
    on the thread that replays it, or ``process``, in a worker process per session
    thread (``evaluation.decoded``) while this process steps the model; the same
    reports. Not used with ``processes`` > 1 (each worker decodes its own).
    ``on_session(done, total, path, seconds)`` after each session, in that order: a
    long run's progress.
    """
    if every < 1:
        msg = f"--every must be at least 1, got {every}"
        raise EvaluationError(msg)
    if jobs < 1:
        msg = f"--jobs must be at least 1, got {jobs}"
        raise EvaluationError(msg)
    if processes < 1:
        msg = f"--processes must be at least 1, got {processes}"
        raise EvaluationError(msg)
    windows = window_graphs(runtimes) if every > 1 else None
    decode = decode_where(decode, paths, jobs, processes)

    def one(p: str | Path) -> tuple[list[SessionReplay], float]:
        started = time.perf_counter()
        decoder = decoders.get()  # a session thread's own, while it replays
        try:
            replays = replay_session_models(
                p,
                runtimes,
                pairing,
                every=every,
                windows=windows,
                batch=batch,
                jobs=jobs,
                pool=pool,
                decoder=decoder,
            )
        finally:
            decoders.put(decoder)
        for replay in replays:
            replay.drop_predictions()  # memory stays that of a session or two, however many
        return replays, time.perf_counter() - started

    began, began_cpu = time.perf_counter(), time.process_time()
    if processes > 1:
        workers = ProcessReplays(runtimes, processes, pairing, every, batch)
        per_session = list(workers.replays(paths, on_session))
        seconds = time.perf_counter() - began
        cpu_seconds = time.process_time() - began_cpu + workers.cpu_seconds
        return _reports(runtimes, per_session, every, windows, seconds, cpu_seconds, processes)
    per_session = []
    # With jobs > 1, two sessions at a time: one decodes while the other's last chunk is
    # stepped and scored, so that the threads stepping segments seldom wait for work.
    in_flight = SESSIONS_IN_FLIGHT if jobs > 1 else 1
    decoders: queue.SimpleQueue[DecodeWorker | None] = queue.SimpleQueue()
    for _ in range(min(in_flight, len(paths))):
        decoders.put(DecodeWorker(pairing).start() if decode == "process" else None)
    with (
        ThreadPoolExecutor(jobs, thread_name_prefix="scotti-eval") as pool,
        ThreadPoolExecutor(in_flight, thread_name_prefix="scotti-eval-session") as sessions,
        quick_gil_handoff(),
    ):
        futures = [sessions.submit(one, p) for p in paths]
        try:
            for i, (p, future) in enumerate(zip(paths, futures, strict=True)):
                replays, took = future.result()
                per_session.append(replays)
                if on_session is not None:
                    on_session(i + 1, len(paths), Path(p), took)
        finally:
            for future in futures:  # a session that failed: the ones after it never start
                future.cancel()
            while not decoders.empty():
                if (worker := decoders.get()) is not None:
                    worker.close()
    seconds = time.perf_counter() - began
    cpu_seconds = time.process_time() - began_cpu
    if decode == "process":  # the workers' CPU is the evaluation's too
        cpu_seconds += sum(r[0].decode_cpu_s for r in per_session)
    reports = _reports(runtimes, per_session, every, windows, seconds, cpu_seconds, 1, jobs)
    for report in reports:
        report["rate"]["decode"] = decode
    return reports


def decode_where(decode: str, paths: Sequence[str | Path], jobs: int, processes: int) -> str:
    """``here`` or ``process`` for ``decode`` = ``auto``: a decode process where a core is
    free for it (``jobs`` > 1, one process) and the sessions are long enough to repay
    its start (``AUTO_DECODE_BYTES``); else as asked."""
    if decode not in DECODE_CHOICES:
        msg = f"--decode must be one of {', '.join(DECODE_CHOICES)}, got {decode!r}"
        raise EvaluationError(msg)
    if processes > 1:
        return "here"  # in the workers: each decodes the sessions it replays
    if decode != "auto":
        return decode
    if jobs < 2:
        return "here"
    try:
        size = sum(Path(p).stat().st_size for p in paths)
    except OSError:
        return "here"  # the replay says what is wrong with the file
    return "process" if size >= AUTO_DECODE_BYTES else "here"


def _reports(
    runtimes: Sequence[StepModel],
    per_session: list[list[SessionReplay]],
    every: int,
    windows: list[ScottiRuntime] | None,
    seconds: float,
    cpu_seconds: float,
    processes: int,
    jobs: int = 1,
) -> list[dict[str, Any]]:
    """One report per model, with the replay's rate (shared by the models)."""
    reports = [
        _report(
            runtime, [replays[i] for replays in per_session], every, windows[i] if windows else None
        )
        | {"rate": rate(per_session, i, seconds, cpu_seconds)}
        for i, runtime in enumerate(runtimes)
    ]
    # The peak so far, scoring included (its pooled frames are the largest part): this
    # process's, or with workers the larger of it and the largest worker's.
    peak_rss_mb = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)  # Linux: kB
    if processes > 1:
        peak_rss_mb = max(peak_rss_mb, peak_rss_children_mb())
    for report in reports:
        report["rate"]["peak_rss_mb"] = peak_rss_mb
        report["rate"]["jobs"] = jobs
        report["rate"]["processes"] = processes
    return reports


def rate(
    per_session: list[list[SessionReplay]], model: int, seconds: float, cpu_seconds: float
) -> dict[str, Any]:
    """How fast the replay went: paired frames per second of wall time and of this
    process's CPU time and its decode workers' (on a shared host the CPU figure is
    the one-core rate), the time spent in this model's graph and in reading and
    decoding the files, and the rate of everything else (reading, decoding,
    assembly, pairing, scoring). Every model's replay of a session is one pass, so
    the models share the wall and CPU figures."""
    replays = [replays[model] for replays in per_session]
    pairs = sum(r.pairs for r in replays)
    model_s = sum(r.model_cpu_s for r in replays)  # onnxruntime, 1 thread: this thread
    rest_s = cpu_seconds - sum(r.model_cpu_s for per in per_session for r in per)
    decode_s = sum(r.decode_cpu_s for r in replays)  # one decoding per session, all models
    return {
        "paired_frames": pairs,
        "seconds": round(seconds, 3),
        "cpu_seconds": round(cpu_seconds, 3),
        "frames_per_s": round(pairs / seconds, 1) if seconds > 0 else None,
        "frames_per_cpu_s": round(pairs / cpu_seconds, 1) if cpu_seconds > 0 else None,
        "model_cpu_seconds": round(model_s, 3),
        # reading the file and the one frame path, in the caller or its decode worker
        "decode_cpu_seconds": round(decode_s, 3),
        "without_model_frames_per_cpu_s": round(pairs / rest_s, 1) if rest_s > 0 else None,
    }


def _report(
    runtime: StepModel,
    replays: list[SessionReplay],
    every: int,
    window_graph: ScottiRuntime | None,
) -> dict[str, Any]:
    frames = FrameScores.concat([r.scores for r in replays])
    report: dict[str, Any] = {
        "model": {
            "path": str(runtime.path),
            "sha256": runtime.sha256,
            "window": runtime.window,
            "embed_dim": runtime.embed_dim,
            "threads": runtime.threads,
        },
        "every": every,
        "graph": "step" if window_graph is None else "window",
        "sessions": [r.summary() | {"metrics": task_metrics(r.scores)} for r in replays],
        "subjects": sorted({r.subject for r in replays}),
    }
    if not isinstance(runtime, ScottiRuntime):  # the streaming-native form says so
        report["model"] |= {"step_kind": "kv_cache", "receptive_field": runtime.receptive_field}
    if window_graph is None:
        # Segments side by side: throughput per step-graph row (warm-up rows included).
        batches = [b for r in replays for b in r.step_batches]
        rows = sum(n for _, n in batches)
        report["step_ms_per_row"] = {
            "mean": sum(ms for ms, _ in batches) / rows if rows else float("nan"),
            "rows": rows,
            "batches": len(batches),
            "largest_batch": max((n for _, n in batches), default=0),
        }
    else:
        report["model"]["window_graph"] = {
            "path": str(window_graph.path),
            "sha256": window_graph.sha256,
        }
        # Batched throughput, not the latency of one streaming step: named apart on purpose.
        batches = [b for r in replays for b in r.window_batches]
        report["window_ms_per_prediction"] = window_timing(batches)
    report |= score(frames)
    flags: Counter[str] = Counter()
    actions: Counter[str] = Counter()
    for r in replays:
        flags.update(r.flags)
        actions.update(r.actions)
    report["ood"] = shares_of(flags)  # every prediction
    report |= what_was_made(replays, actions, flags)
    return report


def what_was_made(
    replays: list[SessionReplay], actions: Counter[str], flags: Counter[str]
) -> dict[str, Any]:
    """What a replay tells without labels: whether anything was scored, the sessions
    that had no labels, and what the model made of every session (a recording
    without labels is still worth a look: are the flags sane, what does it see)."""
    return {
        "scored": any(r.evaluated for r in replays),
        "unlabelled_sessions": [r.path for r in replays if not r.labels],
        "predictions": sum(r.predictions for r in replays),
        "actions_predicted": dict(actions),  # published: no flag withheld them
        "actions_withheld": flags["any"],
        "pairs": sum(r.pairs for r in replays),
        "degraded_pairs": sum(r.degraded_pairs for r in replays),
    }
