"""Running the coverage grid: one job per cell (or scene file), a checkpoint per job in
the cache, ``--jobs`` processes, a deadline, a progress line per job.

A job's checkpoint is ``CACHE/cells/KEY.json``; KEY hashes what decides its
result: the scenes of its people, the model's bytes and the source of the
simulator, the model room, the evaluation room and the scorer
(``code_digest``). A job whose checkpoint is there is not run again; a change
of any of those gives new keys, so a rerun after one redoes what it changed.
"""

from __future__ import annotations

import contextlib
import json
import os
import time
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

from common import ROOT, from_root, source_digest
from coverage_grid import Cell, digest
from coverage_score import same_motion, score_scenes
from scotti.models.kv_streaming import StepModel, open_step_model
from scotti.sim import SimError
from scotti.sim.scene import Scene

# Sources whose change can change a cell's figures (globs relative to the repository).
CODE: Final = (
    "sim/**/*.py",
    "models/*.py",
    "evaluation/*.py",
    "firmware_protocol/*.py",
    "daemon/inference/window.py",
    "experiments/coverage_score.py",
)


def code_digest(root: Path = ROOT) -> str:
    """A hash of every source file in ``CODE`` (names and bytes)."""
    return source_digest(CODE, root)


@dataclass(frozen=True)
class Job:
    """A cell of the grid (``cell``) or a scene file (``scene_file``), with its scenes."""

    key: str
    label: str
    scenes: tuple[dict[str, Any], ...]
    cell: Cell | None = None
    scene_file: str | None = None
    # The people's baseline scenes, when the cell's parameter acts on the motion only:
    # a cell whose motions are the baseline's is marked unchanged, not simulated.
    baselines: tuple[dict[str, Any], ...] | None = None

    def describe(self) -> dict[str, Any]:
        if self.cell is not None:
            return {"action": self.cell.action, "path": self.cell.path, "value": self.cell.value}
        return {"scene_file": self.scene_file}


def cell_job(
    cell: Cell, scenes: list[dict[str, Any]], baselines: list[dict[str, Any]] | None, salt: str
) -> Job:
    key = digest({"scenes": scenes, "salt": salt, "unchanged_check": baselines is not None})
    return Job(key, f"{cell.action}: {cell.label}", tuple(scenes), cell=cell,
               baselines=None if baselines is None else tuple(baselines))  # fmt: skip


def scene_file_job(path: Path, salt: str) -> Job:
    text = path.read_text(encoding="utf-8")
    scene = Scene.from_toml_text(text, path.name)
    raw = scene.model_dump(mode="json")
    key = digest({"scene_file": path.name, "scene": raw, "salt": salt})
    return Job(key, f"scene {path.name}", (raw,), scene_file=from_root(path))


@dataclass
class Outcome:
    """What a run did: results by key, and how many jobs were run, reused or left."""

    results: dict[str, dict[str, Any]] = field(default_factory=dict)
    simulated: int = 0  # jobs whose sessions were rendered and scored in this run
    unchanged: int = 0  # jobs found to leave the motion as the baseline's, in this run
    reused: int = 0  # jobs whose checkpoint was already in the cache
    left: int = 0  # jobs not started: the deadline came
    wall_s: float = 0.0

    def add(self, other: Outcome) -> None:
        """Another run's jobs into this one (``--refine`` rounds)."""
        self.results.update(other.results)
        self.simulated += other.simulated
        self.unchanged += other.unchanged
        self.reused += other.reused
        self.left += other.left
        self.wall_s += other.wall_s


_RUNTIMES: dict[str, StepModel] = {}  # per worker process: the model, loaded once


def run_job(job: Job, model: str, workdir: str, keep: bool) -> dict[str, Any]:
    """Score one job (in a worker): unchanged, or its sessions rendered and replayed."""
    started = time.process_time()
    out: dict[str, Any] = {"key": job.key, "label": job.label, **job.describe()}
    if job.baselines is not None and same_motion(job.scenes, job.baselines):
        return out | {"unchanged": True, "cpu_s": round(time.process_time() - started, 3)}
    if model not in _RUNTIMES:
        _RUNTIMES[model] = open_step_model(model, threads=1)  # either form
    scenes = [Scene.model_validate(raw) for raw in job.scenes]
    try:
        result = score_scenes(scenes, _RUNTIMES[model], Path(workdir) / job.key, keep=keep)
    except SimError as exc:  # a scene the schema accepts and the simulator refuses: a finding
        first = str(exc).splitlines()[0]
        return out | {"unchanged": False, "error": first,
                      "cpu_s": round(time.process_time() - started, 3)}  # fmt: skip
    result["cpu_s"] = round(time.process_time() - started, 3)  # the motion check included
    if not keep:
        _remove_empty(Path(workdir) / job.key)
    return out | {"unchanged": False} | result


def _remove_empty(folder: Path) -> None:
    with contextlib.suppress(OSError):  # sessions kept there (--keep-sessions), or never made
        folder.rmdir()


def checkpoint(cache: Path, key: str) -> Path:
    return cache / "cells" / f"{key}.json"


def run_jobs(
    jobs: list[Job],
    *,
    model: Path,
    cache: Path,
    processes: int = 1,
    max_minutes: float | None = None,
    keep: bool = False,
    say: Callable[[str], None] = print,
) -> Outcome:
    """Run every job not in the cache; stop starting new ones at the deadline."""
    began = time.monotonic()
    deadline = None if max_minutes is None else began + 60.0 * max_minutes
    outcome = Outcome()
    todo: list[Job] = []
    for job in jobs:
        path = checkpoint(cache, job.key)
        if path.is_file():
            outcome.results[job.key] = json.loads(path.read_text())
            outcome.reused += 1
        else:
            todo.append(job)
    say(f"coverage: {len(jobs)} jobs, {outcome.reused} in the cache, {len(todo)} to run")
    workdir = str(cache / "sessions")
    done = 0

    def record(job: Job, result: dict[str, Any]) -> None:
        nonlocal done
        done += 1
        path = checkpoint(cache, job.key)
        path.parent.mkdir(parents=True, exist_ok=True)
        partial = path.with_suffix(".partial")
        partial.write_text(json.dumps(result, indent=1) + "\n")
        os.replace(partial, path)  # a checkpoint is whole or absent
        outcome.results[job.key] = result
        if result.get("unchanged"):
            outcome.unchanged += 1
        else:
            outcome.simulated += 1
        say(progress_line(done, len(todo), result, time.monotonic() - began))

    def late() -> bool:
        return deadline is not None and time.monotonic() > deadline

    if processes <= 1:
        for i, job in enumerate(todo):
            if late():
                outcome.left = len(todo) - i
                break
            record(job, run_job(job, str(model), workdir, keep))
    else:
        queue = list(todo)
        with ProcessPoolExecutor(max_workers=processes) as pool:
            running: dict[Future[dict[str, Any]], Job] = {}
            while queue or running:
                while queue and len(running) < processes and not late():
                    job = queue.pop(0)
                    running[pool.submit(run_job, job, str(model), workdir, keep)] = job
                if not running:
                    break
                finished, _ = wait(running, return_when=FIRST_COMPLETED)
                for future in finished:
                    record(running.pop(future), future.result())
            outcome.left = len(queue)
    outcome.wall_s = time.monotonic() - began
    if outcome.left:
        say(f"coverage: --max-minutes reached, {outcome.left} jobs left for the next run")
    return outcome


def progress_line(done: int, total: int, result: dict[str, Any], elapsed_s: float) -> str:
    head = f"[{done}/{total}] {result['label']}"
    if "error" in result:
        return f"{head}: the simulator refused it: {result['error']}"
    if result.get("unchanged"):
        return f"{head}: same motion as the baseline"
    m = result["metrics"]
    acc = m.get("action_accuracy")
    app = m.get("app")
    left = elapsed_s / done * (total - done)
    return (
        f"{head}: accuracy {_pct(acc)}, APP {_num(app)}, "
        f"{result['cpu_s']:.1f} CPU s; {elapsed_s / 60:.1f} min so far, ~{left / 60:.0f} min left"
    )


def _pct(value: float | None) -> str:
    return "-" if value is None else f"{100 * value:.1f} %"


def _num(value: float | None) -> str:
    return "-" if value is None else f"{value:.3f}"
