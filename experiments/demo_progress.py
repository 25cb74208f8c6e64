"""Does progress sweep 0 -> 1, and how many repetitions does the daemon count, on the demo's scene?

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
- repetitions counted the daemon's way: every prediction in time order through
  ``daemon.inference.published.publish`` (the pipeline's own rule: a flagged
  prediction is withheld and the counter neither counts nor forgets), the
  counter started over where the window restarted; ``--high``/``--low`` try
  other thresholds of the counter;
- the same ignoring the flags (not what the daemon publishes);
- what the daemon's counter completes on the labels of the times predicted for;
- the share of the predictions of that action (most likely action) that a
  flag withheld.

A repetition is credited to the action the counter was counting. Then a strip
of the first squats: predicted progress against the label, one character per
frame. The demo scene is not in the training corpus (its own seed and subject).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from collections import Counter
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np
from common import ROOT
from scotti.daemon.inference.published import Published, publish
from scotti.daemon.inference.repetitions import RepetitionCounter
from scotti.daemon.input.simulated import resolve_scene
from scotti.evaluation.frames import FrameSet
from scotti.evaluation.replay import replay_session
from scotti.evaluation.sampling import Prediction
from scotti.models import contract
from scotti.models.kv_streaming import open_step_model
from scotti.models.ood import withheld

LEVELS = " .:-=+*#%@"  # 0..1 in ten steps


def strip(values: np.ndarray) -> str:
    idx = np.clip((np.nan_to_num(values, nan=0.0) * (len(LEVELS) - 1)).round(), 0, 9)
    return "".join(LEVELS[int(i)] for i in idx)


def streams(made: Sequence[Prediction]) -> list[Sequence[Prediction]]:
    """The predictions cut where the daemon's window restarted, its counter with it.

    A restart leaves at least T-1 frames without a prediction while the window
    warms up again, so a break in the predictions' seqs is where one happened
    (the replay keeps no other mark of it). Pairs without a seq would break it
    too, and the daemon counts through those: the script prints the restarts
    beside the stretches, equal where there were none."""
    cuts = [i for i in range(1, len(made)) if made[i].ext != made[i - 1].ext + 1]
    return [made[a:b] for a, b in zip([0, *cuts], [*cuts, len(made)], strict=True)]


def published(
    made: Sequence[Prediction], *, high: float, low: float, flags: bool = True
) -> list[Published]:
    """What the daemon publishes for each of a replay's predictions, in order: each through
    ``publish`` with the counter started over at every restart (``flags=False``: as if no
    flag withheld anything)."""
    out: list[Published] = []
    for stream in streams(made):
        counter = RepetitionCounter(high, low)
        for m in stream:
            out.append(
                publish(int(np.argmax(m.probs)), m.progress, m.flags if flags else (), counter)
            )
    return out


def completed(stream: Iterable[Published]) -> Counter[int]:
    """Repetitions completed per action over a published stream.

    Every increment counts, also across the counter starting over: a session
    holds several sets of one action, and the count the counter ends with would
    only be the last set's. The counter counts only while the published action is
    the one it counts, so each repetition is credited to that action. A count that
    comes back after a pause in its set (standing, then the same action at the
    count it stood at) completes nothing."""
    done: Counter[int] = Counter()
    action, last = None, 0
    for p in stream:
        if p.withheld is not None or p.repetition < 0:
            continue  # withheld: neither counted nor forgot; standing counts nothing
        if p.action == action and p.repetition > last:
            done[p.action] += p.repetition - last
        action, last = p.action, p.repetition
    return done


def labelled(frames: FrameSet) -> Counter[int]:
    """What the daemon's counter completes on the labels of the times predicted for
    (the window's warm-up has none: the daemon could not count there)."""
    counter = RepetitionCounter()
    steps = zip(frames.action_true.tolist(), frames.progress_true.tolist(), strict=True)
    return completed(publish(a, p, (), counter) for a, p in steps)


def withheld_share(made: Sequence[Prediction], action: int) -> float:
    """Share of the predictions whose most likely action is ``action`` that a flag withheld."""
    of = [m for m in made if int(np.argmax(m.probs)) == action]
    return sum(withheld(m.flags) is not None for m in of) / len(of) if of else float("nan")


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
    runtime = open_step_model(args.model, threads=1)  # either form, as the daemon
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
    daemon = completed(published(replay.made, high=high, low=low))
    unflagged = completed(published(replay.made, flags=False, high=high, low=low))
    truth_count = labelled(replay.frames)
    f = replay.frames
    progress = np.where(np.isfinite(f.progress_pred), f.progress_pred, np.nan)
    print(
        f"{args.model.name} on {name}: {len(replay.made)} predictions"
        f" ({replay.window_restarts} window restarts, {len(streams(replay.made))} stretches),"
        f" {len(f.action_true)} scored; counter high {high}, low {low}"
    )
    print(
        "action            frames  p5    p95   reach <0.2 and >0.8  MSE    "
        "counted: daemon  no flags  labels  withheld"
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
        print(
            f"{contract.ACTIONS[a]:17s} {rows.size:6d}  {p5:.2f}  {p95:.2f}  "
            f"{reaches(pred, truth):17.0%}     {mse:.4f} {daemon[a]:14d} {unflagged[a]:9d}"
            f" {truth_count[a]:7d} {withheld_share(replay.made, a):9.1%}"
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
