"""Coverage: the shipped model over every parameter a scene may set, action by action.

    python experiments/coverage.py [--people 3] [--seconds 40] [--model M] [--jobs 1]
        [--max-minutes MIN] [--cache runs/coverage] [--write OUT.md]
        [--action A ...] [--param PREFIX ...] [--scenes DIR | --no-scenes] [--keep-sessions]

For every action of the contract (standing included) and every field of the
scene schema (experiments/coverage_grid.py reads them from sim/scene.py, the
insole and the effect registry), a cell simulates ``--people`` people doing
the action for ``--seconds`` with that field at its schema minimum, then at its
maximum, everything else at the scene's default; each person's session is
replayed through the daemon's path as ``scotti eval`` does (the shipped model
unless ``--model``) and the cell keeps accuracy, APP, MPJPE, progress MSE, the
flag shares, and how many predictions were wrong and went out unflagged
(experiments/coverage_score.py). Every scene file of sim/scenes is scored as
shipped too. The markdown gets the headline (the worst cell), the goals,
the unfamiliar flag as a detector of wrong predictions and the tables
(experiments/coverage_doc.py): docs/coverage.md for the shipped model over the
whole grid, CACHE/coverage.md for another model or a restricted grid (``--write``
chooses).

Each cell is checkpointed in the cache as it is scored; a rerun takes what is
there (``--fresh`` ignores it) and ``--max-minutes`` stops starting cells, so a
long sweep can be run in pieces. ``--action`` and ``--param`` (a prefix of the
field's path, e.g. ``insole`` or ``subject.depth``) restrict the grid.
"""

from __future__ import annotations

import argparse
import hashlib
import shutil
import subprocess
import sys
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

from common import ROOT, from_root, utc_now, write_card_section
from coverage_doc import Row, Summary, card_section, markdown
from coverage_grid import Cell, GridError, Parameter, cells, digest, parameters, people
from coverage_refine import refined, refinements
from coverage_run import Job, Outcome, cell_job, code_digest, run_jobs, scene_file_job
from scotti.models.contract import ACTIONS
from scotti.sim import SimError
from scotti.sim.scene import Scene

SCENES = ROOT / "sim" / "scenes"
DEFAULT_MODEL = ROOT / "models" / "scotti-default.onnx"
DOC = ROOT / "docs" / "coverage.md"  # the shipped model's table
CARD = DEFAULT_MODEL.with_suffix(".card.md")  # its card quotes the headline and the goals


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python experiments/coverage.py",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--people", type=int, default=3, help="simulated people per cell")
    p.add_argument("--seconds", type=float, default=40.0, help="seconds of the action per cell")
    p.add_argument("--model", type=Path, default=DEFAULT_MODEL, help="streaming step graph")
    p.add_argument("--jobs", type=int, default=1, help="processes side by side")
    p.add_argument("--max-minutes", type=float, default=None, help="start no cell after this")
    p.add_argument("--cache", type=Path, default=ROOT / "runs" / "coverage")
    p.add_argument("--fresh", action="store_true", help="ignore the cache's checkpoints")
    p.add_argument(
        "--write",
        type=Path,
        help="the markdown (default: docs/coverage.md for the shipped model over the whole "
        "grid, else CACHE/coverage.md)",
    )
    p.add_argument("--action", action="append", choices=ACTIONS, help="only these actions")
    p.add_argument("--param", action="append", help="only fields whose path starts so")
    p.add_argument("--scenes", type=Path, default=SCENES, help="scene files scored as shipped")
    p.add_argument("--no-scenes", action="store_true", help="skip the scene files")
    p.add_argument("--keep-sessions", action="store_true", help="keep the session files")
    p.add_argument(
        "--refine",
        type=int,
        default=0,
        help="rounds of one more value between where each field's run ends and where it "
        "breaks (experiments/coverage_refine.py)",
    )
    return p


def plan(args: argparse.Namespace, salt: str) -> tuple[list[Job], list[Job], Summary]:
    """The grid's jobs, the scene files' jobs, and the doc's summary (figures to come)."""
    swept = [
        p for p in parameters() if not args.param or any(p.path.startswith(x) for x in args.param)
    ]
    actions = tuple(args.action) if args.action else ACTIONS
    grid = cell_jobs(cells(actions, swept), swept, args, salt)
    found = [] if args.no_scenes else sorted(args.scenes.glob("*.toml"))
    files = [scene_file_job(f, salt) for f in found]
    summary = Summary(
        command="",
        people=args.people,
        seconds=args.seconds,
        model=from_root(args.model),
        model_sha="",
        commit=_commit(),
        date=utc_now(),
        actions=actions,
        parameters=tuple(swept),
        cpu_minutes=0.0,
        wall_minutes=0.0,
        jobs_left=0,
    )
    return grid, files, summary


def cell_jobs(
    grid: list[Cell], swept: Sequence[Parameter], args: argparse.Namespace, salt: str
) -> list[Job]:
    """A job per cell: its people's scenes, and their baselines where only motion moves."""
    persons = people(args.people)
    moving = {p.path for p in swept if p.moves_only}
    jobs = []
    for cell in grid:
        scenes = [cell.scene(person, args.seconds) for person in persons]
        for raw in scenes:
            _validate(raw, cell)
        baselines = None
        if cell.path in moving:
            baselines = [Cell(cell.action).scene(person, args.seconds) for person in persons]
        jobs.append(cell_job(cell, scenes, baselines, salt))
    return jobs


def refine(
    args: argparse.Namespace, salt: str, grid: list[Job], summary: Summary, outcome: Outcome
) -> tuple[list[Job], Summary]:
    """``--refine`` rounds: a value between each run's end and its break, every action,
    scored into ``outcome``; the grid and the summary's parameters with them."""
    for _ in range(args.refine):
        rows = [Row(outcome.results[j.key]) for j in grid if j.key in outcome.results]
        added = refinements(summary, rows)
        if not added or outcome.left:
            break
        swept = refined(summary.parameters, added)
        more = [Cell(a, path, v) for path, values in added.items() for v in values
                for a in summary.actions]  # fmt: skip
        jobs = cell_jobs(more, swept, args, salt)
        left = None
        if args.max_minutes is not None:
            left = max(0.0, args.max_minutes - outcome.wall_s / 60.0)
        outcome.add(run_jobs(jobs, model=args.model, cache=args.cache, processes=args.jobs,
                             max_minutes=left, keep=args.keep_sessions))  # fmt: skip
        grid = grid + jobs
        summary = replace(summary, parameters=swept)
    return grid, summary


def _validate(raw: dict[str, object], cell: Cell) -> None:
    """A cell's scene must be one the schema accepts: else the grid is wrong (one line)."""
    try:
        scene = Scene.model_validate(raw)
        scene.check_effects()
    except (ValueError, SimError) as exc:
        first = str(exc).splitlines()[0]
        msg = f"{cell.action}, {cell.label}: the schema refuses the cell's scene: {first}"
        raise GridError(msg) from None


def shipped_whole_grid(args: argparse.Namespace) -> bool:
    """Whether the run is the shipped model over the whole grid (what its card may quote)."""
    whole = not args.action and not args.param
    return whole and args.model.resolve() == DEFAULT_MODEL.resolve()


def doc_target(args: argparse.Namespace) -> Path:
    """Where the markdown goes. docs/coverage.md describes the shipped model over the whole
    grid, so only such a run writes it unless ``--write`` says otherwise: a candidate's run,
    or a run restricted by ``--action`` or ``--param``, goes beside its cache instead of
    quietly replacing the shipped model's table with its own."""
    if args.write is not None:
        return args.write
    if shipped_whole_grid(args):
        return DOC
    return args.cache / "coverage.md"


def _commit() -> str:
    proc = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True
    )
    return proc.stdout.strip() or "unknown"


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    shown = " ".join(argv if argv is not None else sys.argv[1:])
    try:
        if args.people < 1 or args.seconds <= 0 or args.jobs < 1:
            msg = "--people and --jobs must be at least 1, --seconds above 0"
            raise GridError(msg)
        if not args.model.is_file():
            msg = f"{args.model}: no such model"
            raise GridError(msg)
        model_sha = hashlib.sha256(args.model.read_bytes()).hexdigest()
        salt = digest({"model": model_sha, "code": code_digest()})
        grid, files, summary = plan(args, salt)
        if args.fresh and (args.cache / "cells").is_dir():
            shutil.rmtree(args.cache / "cells")
        outcome = run_jobs(
            grid + files,
            model=args.model,
            cache=args.cache,
            processes=args.jobs,
            max_minutes=args.max_minutes,
            keep=args.keep_sessions,
        )
        grid, summary = refine(args, salt, grid, summary, outcome)
    except (GridError, SimError, OSError) as exc:
        print(f"coverage: {exc}", file=sys.stderr)
        return 2
    results = outcome.results
    rows = [Row(results[j.key]) for j in grid if j.key in results]
    scenes = [results[j.key] for j in files if j.key in results]
    cpu = sum(float(results[j.key].get("cpu_s", 0.0)) for j in grid + files if j.key in results)
    summary = Summary(
        **{
            **summary.__dict__,
            "command": f"python experiments/coverage.py {shown}".strip(),
            "model_sha": model_sha,
            "cpu_minutes": cpu / 60.0,
            "wall_minutes": outcome.wall_s / 60.0,
            "jobs_left": outcome.left,
            "jobs_run": outcome.simulated + outcome.unchanged,
        }
    )
    target = doc_target(args)
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_text(markdown(summary, rows, scenes))
    if target == DOC and shipped_whole_grid(args) and not outcome.left:
        write_card_section(CARD, card_section(summary, rows, scenes), "coverage")
    print(
        f"coverage: {outcome.simulated} cells scored, {outcome.unchanged} unchanged, "
        f"{outcome.reused} from the cache, {outcome.left} left; wrote {target}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
