"""Does progress sweep 0 -> 1 and does the daemon count repetitions, on the demo's scene?

    python experiments/demo_progress.py [--model models/scotti-default.onnx] [--scene demo]
        [--session FILE] [--high H --low L]

Renders the scene (``sim/scenes/demo.toml`` by default: the demo's walking,
squats, lunges, ...) into a session file, or takes ``--session`` (a held-out
subject of the corpus, say), replays it through the daemon's
streaming path (``scotti.evaluation.replay_session``, as ``scotti eval`` does)
and, per repeated action of the script, prints:

- how far the predicted progress sweeps (5th and 95th percentile, and the
  share of repetitions whose predictions reach below 0.2 and above 0.8);
- progress MSE against the labels;
- repetitions the daemon's counter (daemon/inference/repetitions.py, fed the predicted
  action and progress like the pipeline; ``--high``/``--low`` try other
  thresholds) completes, beside what the daemon's counter completes on the
  labels.

Then a strip of the first squats: predicted progress against the label, one
character per frame. The demo scene is not in the training corpus (its own
seed and subject).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from common import ROOT
from scotti.daemon.inference.repetitions import RepetitionCounter
from scotti.daemon.input.simulated import resolve_scene
from scotti.evaluation.replay import replay_session
from scotti.models import contract
from scotti.models.runtime import ScottiRuntime

LEVELS = " .:-=+*#%@"  # 0..1 in ten steps


def strip(values: np.ndarray) -> str:
    idx = np.clip((np.nan_to_num(values, nan=0.0) * (len(LEVELS) - 1)).round(), 0, 9)
    return "".join(LEVELS[int(i)] for i in idx)


def count(
    actions: np.ndarray, progress: np.ndarray, counter: RepetitionCounter | None = None
) -> int:
    """Repetitions the daemon's counter completes over this stretch.

    Every increment counts, also across a reset: the stretch joins the
    script's sets of one action, and the counter starts over at each (the
    action changed in between), so its value at the end would only be the
    last set's.
    """
    counter = counter or RepetitionCounter()
    completed, last = 0, 0
    for a, p in zip(actions.tolist(), progress.tolist(), strict=True):
        n = counter.update(int(a), float(p))
        if n > last:
            completed += n - last
        last = max(n, 0)
    return completed


def reaches(progress: np.ndarray, truth: np.ndarray) -> float:
    """Share of labelled repetitions whose predictions go below 0.2 and above 0.8."""
    wraps = np.flatnonzero(np.diff(truth) < -0.5) + 1  # a label falls back: a new repetition
    pieces = np.split(np.arange(truth.size), wraps)[1:-1]  # complete ones only
    if not pieces:
        return float("nan")
    ok = [progress[i].min() < 0.2 and progress[i].max() > 0.8 for i in pieces]
    return float(np.mean(ok))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python experiments/demo_progress.py")
    parser.add_argument("--model", type=Path, default=ROOT / "models" / "scotti-default.onnx")
    parser.add_argument("--scene", default="demo")
    parser.add_argument("--session", type=Path, help="replay this session file instead")
    parser.add_argument(
        "--high", type=float, help="the counter's arming threshold (default: the daemon's)"
    )
    parser.add_argument(
        "--low", type=float, help="the counter's counting threshold (default: the daemon's)"
    )
    args = parser.parse_args(argv)
    runtime = ScottiRuntime(args.model, threads=1)
    if args.session is not None:
        name = args.session.name
        replay = replay_session(args.session, runtime)
    else:
        scene = resolve_scene(args.scene)
        name = scene.name
        with tempfile.TemporaryDirectory() as tmp:
            session = Path(tmp) / "scene.ses"
            subprocess.run(
                [sys.executable, "-m", "scotti.cli.main", "sim", str(scene), "-o", str(session)],
                check=True,
                cwd=ROOT,
                stdout=subprocess.DEVNULL,
            )
            replay = replay_session(session, runtime)
    default = RepetitionCounter()
    high = default.high if args.high is None else args.high
    low = default.low if args.low is None else args.low
    f = replay.frames
    progress = np.where(np.isfinite(f.progress_pred), f.progress_pred, np.nan)
    print(
        f"{args.model.name} on {name}: {len(f.action_true)} frames scored;"
        f" counter high {high}, low {low}"
    )
    print(
        "action            frames  p5    p95   reps reaching <0.2 and >0.8  MSE    counted / labels"
    )
    for a in sorted(contract.REPEATED_ACTIONS):
        rows = np.flatnonzero(f.action_true == a)
        if rows.size == 0:
            continue
        truth = f.progress_true[rows]
        pred = progress[rows]
        ok = np.isfinite(truth) & np.isfinite(pred)
        mse = float(np.mean((pred[ok] - truth[ok]) ** 2)) if ok.any() else float("nan")
        p5, p95 = np.nanpercentile(pred, [5, 95]) if np.isfinite(pred).any() else (np.nan,) * 2
        counted = count(
            f.action_pred[rows], np.nan_to_num(pred, nan=0.5), RepetitionCounter(high, low)
        )
        labelled = count(f.action_true[rows], np.nan_to_num(truth, nan=0.5))
        print(
            f"{contract.ACTIONS[a]:17s} {rows.size:6d}  {p5:.2f}  {p95:.2f}  "
            f"{reaches(pred, truth):24.0%}     {mse:.4f} {counted:5d} / {labelled}"
        )
    squat = np.flatnonzero(f.action_true == contract.ACTIONS.index("squat"))[:240]
    if squat.size:
        print("\nfirst squats, one character per frame (0 ' ' .. 1 '@'):")
        for start in range(0, squat.size, 80):
            rows = squat[start : start + 80]
            print(f"label      |{strip(f.progress_true[rows])}|")
            print(f"prediction |{strip(progress[rows])}|")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
