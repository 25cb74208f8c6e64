"""Judge a candidate model by the rule of docs/generalisation.md, in one command.

    python experiments/wide_rule.py runs/v14-p1-wide6/models/scotti-ship.onnx \\
        [--shipped models/scotti-default.onnx] [--shipped-flag RECALIBRATED.onnx] \\
        [--every 8] [--json OUT]

The rule was written before any figure of the wide recipe was seen: a
candidate replaces the shipped model only if, on the same replays as the
shipped graph,

1. on partition p1's held-out people (experiments/partitions.json, the
   session files under data/corpus7/realistic, or ``--held-out FOLDER``) it
   keeps the paper's bar (APP >= 0.8952, progress MSE <= 0.0223) and loses
   at most 1 point of accuracy and 0.01 of APP against the shipped model;
2. on the real recordings (experiments/real_data.py, both feet present,
   pooled) its walking share is higher, its published walking share (read
   as walking and sent without a withholding flag) is not lower, and its
   share of confident wrong answers that go out unflagged is not higher;
3. through the foreign sensors of experiments/insole_transfer.py its mean
   accuracy is higher, and no sensor has more than 5 % of predictions wrong
   and unflagged;
4. on every scene of `sim/scenes` (each rendered once, scored by ``scotti
   eval``), for accuracy and for APP apart: where the shipped model meets the
   issue's bar (accuracy >= 95 %, APP >= 0.88) the candidate meets it too;
   where the shipped model misses it, the candidate loses at most 1 point of
   accuracy or 0.01 of APP against it.

Line 4 was revised on 2026-11-29, before the next candidate was trained. It
used to read "on `sim/scenes/squat.toml` its accuracy is higher", written
when the shipped model read that scene at 47 %; at 99.0 % it was decided by
3-9 standing frames after one set, and it looked at no other scene. The
issue's own goal is every scene at 95 % and APP 0.88. Candidates judged by
the old line (runs/v25, v26) keep that verdict (docs/generalisation.md).

Line 2 was revised on 2026-11-29 (session 15), before any candidate was
scored by it: runs/v28 kept every line and read real walking on 92 % of
the windows against 88 %, yet its flag withheld so much that it published
58 % against the shipped model's 79 %: a subscriber would have got less
walking. The published share is what a robot acts on.

Line 2's published share was made like for like on 2026-11-29 (session 16),
before the next candidate (runs/v31) was scored: experiments/
flag_threshold_noise.py found that the draw of the 4,000 held-out windows a
flag's thresholds were fitted on moves the shipped model's published real
walking by 6 points (sd), so a candidate calibrated on another draw could
pass or fail by 1.2 points (v29) on the draw alone. Export now fits the
thresholds on every held-out window (``--ood-held-out-windows``, docs/ood.md),
and the shipped model's published share is read from its own weights with
the flag fitted the same way (``--shipped-flag``, experiments/recalibrate_default.py); its
other figures from the shipped graph as it is.

Lines 2 and 3 gained a reading on 2026-12-01 (session 26), before the
candidate it was written for (runs/v47) was trained: a candidate that keeps the
shipped model's action path (``scotti train --freeze cnn encoder pose_head
action_head``: only progress moves) cannot read real walking or a foreign
sensor otherwise than the shipped model, and the lines as written refused it
for that alone. Declared so (``--action-path-kept``), line 2 first checks that
every real window gets the shipped graph's action probabilities (to
``PATH_TOLERANCE``) and flags, and fails if one does not; its walking share
must then be not lower instead of higher, and line 3's mean accuracy not lower
instead of higher.

Each part runs what its own command runs (``scotti eval --json``, the
experiments' functions) and prints the figures beside each other; the last
line says whether the candidate ships and, if not, which lines failed. Exit 0
either way (a measurement), 2 when something needed is missing.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Final

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import insole_transfer
import real_data
from common import ROOT, ExperimentError, render_is_current, scotti_command, stamp_render
from scotti.models.progress import STEP_CUTS, PeakParams
from scotti.sim.relabel import relabel_session

# The paper's bar (Table 2, real people) and the rule's margins against the shipped model.
PAPER_APP: Final = 0.8952
PAPER_PROGRESS_MSE: Final = 0.0223
MAX_ACCURACY_LOSS: Final = 0.01
MAX_APP_LOSS: Final = 0.01
RULE_LINES: Final = (1, 2, 3, 4)  # the rule's four lines, each run by one part below
MAX_WRONG_UNFLAGGED: Final = 0.05
PARTITION: Final = "p1"
HELD_OUT_DIR: Final = ROOT / "data" / "corpus7" / "realistic"
SCENES: Final = ROOT / "sim" / "scenes"
# The bar for every scene it ships (issue 37, "What to build" 2).
SCENE_ACCURACY: Final = 0.95
SCENE_APP: Final = 0.88
WORK: Final = ROOT / "data" / "wide_rule"
# --action-path-kept: how far an action probability may move on a real window (the
# same weights in the same graph give the same floats; this only absorbs a rebuild).
PATH_TOLERANCE: Final = 1e-6
IN_FORCE: Final = PeakParams().step_cut  # where the stepping actions' steps start today


@dataclass
class Line:
    """One line of the rule: what was compared, both figures, and the verdict."""

    rule: int
    what: str
    candidate: float
    shipped: float
    bar: str
    passed: bool


def held_out_sessions(folder: Path = HELD_OUT_DIR) -> list[Path]:
    """Partition p1's test people, as session files of FOLDER (the corpus the partitions
    name, or the same people rendered by a changed simulator)."""
    partitions = json.loads((ROOT / "experiments" / "partitions.json").read_text())
    part = next(p for p in partitions["partitions"] if p["name"] == PARTITION)
    files = [folder / f"{s}.ses" for s in part["test"]]
    missing = [str(f) for f in files if not f.is_file()]
    if missing:
        msg = f"missing held-out sessions {', '.join(missing)} (export/TRAINING.md makes them)"
        raise ExperimentError(msg)
    return files


def eval_json(sessions: Sequence[Path], models: Sequence[Path]) -> list[dict[str, Any]]:
    """``scotti eval SESSIONS --model A --model B --json``: one report per model."""
    cmd = scotti_command("eval", *sessions, *[a for m in models for a in ("--model", m)], "--json")
    done = subprocess.run(cmd, capture_output=True, text=True, check=False, cwd=ROOT)
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or ["no message"])[-1]
        raise ExperimentError(f"scotti eval exited {done.returncode}: {last}")
    reports = json.loads(done.stdout)
    return list(reports if isinstance(reports, list) else [reports])


def held_out_lines(candidate: Path, shipped: Path, folder: Path = HELD_OUT_DIR) -> list[Line]:
    sessions = held_out_sessions(folder)
    cand, ship = (r["metrics"] for r in eval_json(sessions, [candidate, shipped]))
    return [
        Line(1, "p1 held out: APP (paper's bar)", cand["app"], ship["app"],
             f">= {PAPER_APP}", cand["app"] >= PAPER_APP),
        Line(1, "p1 held out: progress MSE (paper's bar)", cand["progress_mse"],
             ship["progress_mse"], f"<= {PAPER_PROGRESS_MSE}",
             cand["progress_mse"] <= PAPER_PROGRESS_MSE),
        Line(1, "p1 held out: accuracy", cand["action_accuracy"], ship["action_accuracy"],
             f">= shipped - {MAX_ACCURACY_LOSS}",
             cand["action_accuracy"] >= ship["action_accuracy"] - MAX_ACCURACY_LOSS),
        Line(1, "p1 held out: APP against the shipped", cand["app"], ship["app"],
             f">= shipped - {MAX_APP_LOSS}", cand["app"] >= ship["app"] - MAX_APP_LOSS),
    ]  # fmt: skip


def pooled_share(rows: Sequence[dict[str, Any]], key: str, weight: str) -> float:
    """A share pooled over files, each weighted by its count (real_data's pooling)."""
    kept = [r for r in rows if r.get(key) is not None and r.get(weight)]
    total = sum(r[weight] for r in kept)
    return sum(r[key] * r[weight] for r in kept) / total if total else float("nan")


def real_lines(candidate: Path, shipped: Path, path_kept: bool = False) -> list[Line]:
    if not real_data.REALDATA.is_dir():
        raise ExperimentError(f"{real_data.REALDATA}: no such folder (see its README)")
    both_feet = [r for r in real_data.RECORDINGS if not r.one_foot]
    rows: list[dict[str, Any]] = []
    differing = windows = 0
    for rec in both_feet:
        session = real_data.import_file(rec, real_data.REALDATA, real_data.WORK)
        replays = real_data.replay_file(session, [candidate, shipped])
        rows += real_data.score_file(rec, session, [candidate, shipped], replays)
        if path_kept:  # the same replays: the check costs no second pass
            off, compared = pair_difference(replays)
            differing, windows = differing + off, windows + compared
    lines = []
    if path_kept:
        lines.append(
            Line(2, f"real files: windows off the shipped action path (of {windows})",
                 differing, 0, "== 0", differing == 0)
        )  # fmt: skip
    return lines + real_figure_lines(rows, candidate, shipped, path_kept)


def action_path_difference(
    candidate: Path, shipped: Path, sessions: Sequence[Path]
) -> tuple[int, int]:
    """(windows where the two models' predictions differ, windows compared) over the
    sessions replayed through both: a window differs when its action probabilities
    differ by more than PATH_TOLERANCE or its flags differ; a prediction one model
    made and the other did not differs too."""
    differing = windows = 0
    for session in sessions:
        off, compared = pair_difference(real_data.replay_file(session, [candidate, shipped]))
        differing, windows = differing + off, windows + compared
    return differing, windows


def pair_difference(replays: Sequence[Any]) -> tuple[int, int]:
    """(predictions differing, predictions compared) of one session's two replays."""
    mine, theirs = (r.made for r in replays)
    return predictions_differing(mine, theirs), max(len(mine), len(theirs))


def predictions_differing(mine: Sequence[Any], theirs: Sequence[Any]) -> int:
    """How many of two replays' predictions (``evaluation.sampling.Prediction``, matched
    by the time they are for) differ in action probabilities or flags."""
    by_time = {p.ext: p for p in theirs}
    differing = len(set(by_time) ^ {p.ext for p in mine})
    for p in mine:
        other = by_time.get(p.ext)
        if other is None:
            continue
        moved = float(np.max(np.abs(np.asarray(p.probs) - np.asarray(other.probs))))
        differing += moved > PATH_TOLERANCE or set(p.flags) != set(other.flags)
    return differing


def real_figure_lines(
    rows: Sequence[dict[str, Any]], candidate: Path, shipped: Path, path_kept: bool = False
) -> list[Line]:
    """Line 2 from real_data.score_file's rows of both models; with ``path_kept`` (the
    candidate keeps the shipped action path) the walking share may equal the shipped's."""
    mine = {m: [r for r in rows if r["model"] == real_data.label(m)] for m in (candidate, shipped)}
    walk = {m: pooled_share(mine[m], "walking", "walking_windows") for m in mine}
    published = {m: pooled_share(mine[m], "walking_published", "walking_windows") for m in mine}
    key = "confident_wrong_unflagged"
    unflagged = {m: pooled_share(mine[m], key, "predictions") for m in mine}
    more = walk[candidate] >= walk[shipped] if path_kept else walk[candidate] > walk[shipped]
    return [
        Line(2, "real files: walking share", walk[candidate], walk[shipped],
             ">= shipped" if path_kept else "> shipped", more),
        Line(2, "real files: walking published", published[candidate], published[shipped],
             ">= shipped", published[candidate] >= published[shipped]),
        Line(2, "real files: confident wrong, unflagged", unflagged[candidate],
             unflagged[shipped], "<= shipped", unflagged[candidate] <= unflagged[shipped]),
    ]  # fmt: skip


def sensor_lines(candidate: Path, shipped: Path, every: int, path_kept: bool = False) -> list[Line]:
    insole_transfer.simulate_people()
    figures = {m: list(insole_transfer.sensor_figures(m, every)) for m in (candidate, shipped)}
    return sensor_figure_lines(figures, candidate, shipped, path_kept)


def sensor_figure_lines(
    figures: dict[Path, list[dict[str, Any]]], candidate: Path, shipped: Path, path_kept: bool
) -> list[Line]:
    """Line 3 from insole_transfer's rows of both models; with ``path_kept`` the mean
    accuracy may equal the shipped's."""
    mean = {m: float(np.mean([f["accuracy"] for f in figures[m]])) for m in figures}
    worst = {m: max(figures[m], key=lambda f: f["wrong_unflagged"]) for m in figures}
    w_cand, w_ship = worst[candidate], worst[shipped]
    higher = mean[candidate] >= mean[shipped] if path_kept else mean[candidate] > mean[shipped]
    return [
        Line(3, "foreign sensors: mean accuracy", mean[candidate], mean[shipped],
             ">= shipped" if path_kept else "> shipped", higher),
        Line(3, f"foreign sensors: most wrong and unflagged ({w_cand['sensor']})",
             w_cand["wrong_unflagged"], w_ship["wrong_unflagged"],
             f"<= {MAX_WRONG_UNFLAGGED}", w_cand["wrong_unflagged"] <= MAX_WRONG_UNFLAGGED),
    ]  # fmt: skip


def scene_line(scene: str, metric: str, candidate: float, shipped: float) -> Line:
    """Line 4 for one scene and one metric ("accuracy" or "APP"): the issue's bar where
    the shipped model meets it, else at most the rule's margin below the shipped model."""
    bar, margin = {
        "accuracy": (SCENE_ACCURACY, MAX_ACCURACY_LOSS),
        "APP": (SCENE_APP, MAX_APP_LOSS),
    }[metric]
    if shipped >= bar:
        return Line(4, f"{scene}: {metric}", candidate, shipped, f">= {bar}", candidate >= bar)
    return Line(
        4, f"{scene}: {metric}", candidate, shipped, f">= shipped - {margin}",
        candidate >= shipped - margin,
    )  # fmt: skip


def scene_lines(
    candidate: Path,
    shipped: Path,
    scenes: Sequence[Path] | None = None,
    step_cut: str = IN_FORCE,
) -> list[Line]:
    """Line 4: each scene file (all of sim/scenes unless SCENES) rendered into WORK once
    (again when the scene file is newer, or the simulator or the labelling convention
    changed), both models scored on the same replay. With a ``step_cut`` other than the
    convention in force, the replay is the render with its labels remade so
    (``scotti session relabel --step-cut``): a candidate convention is judged without
    editing the one in force."""
    WORK.mkdir(parents=True, exist_ok=True)
    lines: list[Line] = []
    for scene in scenes if scenes is not None else sorted(SCENES.glob("*.toml")):
        session = WORK / f"{scene.stem}.scotti"
        stale = not render_is_current(session)
        if stale or session.stat().st_mtime < scene.stat().st_mtime:
            part = WORK / f".{scene.stem}.part"
            cmd = scotti_command("sim", scene, "-o", part, "--force")
            subprocess.run(cmd, check=True, cwd=ROOT, stdout=subprocess.DEVNULL)
            part.replace(session)
            stamp_render(session)
        if step_cut != IN_FORCE:
            session = relabelled(session, step_cut)
        cand, ship = (r["metrics"] for r in eval_json([session], [candidate, shipped]))
        name = scene.name
        lines.append(scene_line(name, "accuracy", cand["action_accuracy"], ship["action_accuracy"]))
        lines.append(scene_line(name, "APP", cand["app"], ship["app"]))
    return lines


def relabelled(session: Path, step_cut: str) -> Path:
    """``session``'s copy under WORK/step-cut-STEP_CUT with its labels cut so, made
    again whenever the render is newer than it."""
    target: Path = WORK / f"step-cut-{step_cut}" / session.name
    if not target.is_file() or target.stat().st_mtime < session.stat().st_mtime:
        relabel_session(session, target, PeakParams(step_cut=step_cut))
    return target


def verdict(lines: Sequence[Line], run: Sequence[int] = RULE_LINES) -> str:
    """What the lines say; with lines left out (``--lines``) a candidate that fails none
    is not yet decided."""
    failed = sorted({line.rule for line in lines if not line.passed})
    left = [n for n in RULE_LINES if n not in run]
    if not failed and left:
        held = ", ".join(map(str, sorted(set(run))))
        rest = ", ".join(map(str, left))
        return f"NOT DECIDED: line {held} of the rule holds; line {rest} not run"
    if not failed:
        return "SHIPS: every line of the rule holds"
    return "DOES NOT SHIP: line " + ", ".join(map(str, failed)) + " of the rule fails"


def show(line: Line) -> str:
    def fmt(x: float) -> str:
        return f"{x:.4f}"

    mark = "kept" if line.passed else "FAILS"
    figures = f"{fmt(line.candidate):>8s} {fmt(line.shipped):>8s}"
    return f"{line.rule}  {line.what:55s} {figures}  {line.bar:22s} {mark}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python experiments/wide_rule.py",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("candidate", type=Path, help="the step graph that would ship")
    parser.add_argument("--shipped", type=Path, default=ROOT / "models" / "scotti-default.onnx")
    parser.add_argument(
        "--shipped-flag",
        type=Path,
        help="line 2's shipped model: the shipped weights with the flag fitted as the "
        "candidate's was (experiments/recalibrate_default.py; default: --shipped as it is)",
    )
    parser.add_argument("--every", type=int, default=8, help="insole_transfer's --every")
    parser.add_argument(
        "--held-out",
        type=Path,
        default=HELD_OUT_DIR,
        help="the folder holding p1's held-out sessions (another render of the same people "
        "when the simulator changed; both models are scored on them)",
    )
    parser.add_argument("--json", type=Path, help="also write the lines here")
    parser.add_argument(
        "--action-path-kept",
        action="store_true",
        help="the candidate keeps the shipped model's action path (only its progress head "
        "was trained): line 2 checks every real window's actions and flags against the "
        "shipped graph's, and lines 2 and 3 then ask for figures not lower, not higher",
    )
    parser.add_argument(
        "--lines",
        type=int,
        nargs="+",
        choices=RULE_LINES,
        default=list(RULE_LINES),
        help="run only these lines (1 and 2 take minutes, 3 and 4 half an hour): a candidate "
        "that fails one is decided; one that holds them is not, until all four have run",
    )
    parser.add_argument(
        "--step-cut",
        choices=STEP_CUTS,
        default=IN_FORCE,
        help="judge line 4 on the scenes' labels with the stepping actions cut so (a "
        "candidate convention, models/progress.py; give line 1 a --held-out folder "
        "relabelled the same way: scotti session relabel --step-cut)",
    )
    args = parser.parse_args(argv)
    candidate, shipped = args.candidate.resolve(), args.shipped.resolve()
    shipped_flag = (args.shipped_flag or args.shipped).resolve()
    every_part: dict[int, Callable[[], list[Line]]] = {
        1: lambda: held_out_lines(candidate, shipped, args.held_out.resolve()),
        2: lambda: real_lines(candidate, shipped_flag, args.action_path_kept),
        3: lambda: sensor_lines(candidate, shipped, args.every, args.action_path_kept),
        4: lambda: scene_lines(candidate, shipped, step_cut=args.step_cut),
    }
    parts = [every_part[n] for n in sorted(set(args.lines))]
    try:
        for path in (candidate, shipped, shipped_flag):
            if not path.is_file():
                raise ExperimentError(f"{path}: no such model")
        print(f"rule  {'what':55s} {'candidate':>8s} {'shipped':>8s}  {'bar':22s}", flush=True)
        lines: list[Line] = []
        for part in parts:
            started = time.monotonic()
            for line in part():
                lines.append(line)
                print(show(line), flush=True)
            print(f"   ({time.monotonic() - started:.0f} s)", flush=True)
        print(verdict(lines, args.lines))
        if args.json:
            out = {
                "candidate": str(candidate),
                "shipped": str(shipped),
                "shipped_flag": str(shipped_flag),
                "lines": [asdict(line) for line in lines],
                "lines_run": sorted(set(args.lines)),
                "action_path_kept": args.action_path_kept,
                "verdict": verdict(lines, args.lines),
            }
            args.json.write_text(json.dumps(out, indent=1) + "\n")
    except ExperimentError as exc:
        print(f"wide_rule: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
