"""Where in a repetition does the progress error sit? Squared error by the label's tenth.

    python experiments/progress_error_sites.py --model models/scotti-default.onnx \
        data/corpus7/realistic/subject-{005,007,010,013,014}.ses [--show walking]

Replays the session files through the daemon's streaming path (as ``scotti
eval`` does) and pools every frame whose progress is labelled and predicted.
Per tenth of the label (0-0.1, ..., 0.9-1.0) it prints the share of frames,
the mean prediction, the MSE and the share of the whole squared error; then,
per action, the MSE and how much of the action's squared error lies at the
sawtooth's ends (label below 0.1 or above 0.9: a repetition's last frames and
the next one's first, where a standing-up body looks the same). ``--show
ACTION`` also prints labels and predictions of that action frame by frame
(its pooled frames ``--from`` on, 60 of them): where a model hedges at a wrap.

Why: progress is a sawtooth. A repetition's last frames (label near 1) and
the next one's first (near 0) are both someone standing upright, so a model
that hedges there loses most where the label wraps. Whether the held-out
error sits there or is spread over the whole repetition says whether more
training of the same kind can close the gap to the paper's bar.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scotti.evaluation.replay import replay_session
from scotti.models import contract
from scotti.models.kv_streaming import open_step_model

ENDS = (0.1, 0.9)  # a label below the first or above the second is at the sawtooth's ends


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python experiments/progress_error_sites.py")
    parser.add_argument("sessions", nargs="+", type=Path)
    parser.add_argument("--model", type=Path, default=Path("models/scotti-default.onnx"))
    parser.add_argument("--show", choices=contract.ACTIONS, help="print one action's frames")
    parser.add_argument("--from", dest="first", type=int, default=200, metavar="N")
    args = parser.parse_args(argv)
    runtime = open_step_model(args.model, threads=1)  # either form, as the daemon
    truths, preds, actions = [], [], []
    for path in args.sessions:
        f = replay_session(path, runtime).frames
        truth = np.asarray(f.progress_true, dtype=np.float64)
        pred = np.asarray(f.progress_pred, dtype=np.float64)
        ok = np.isfinite(truth) & np.isfinite(pred)
        truths.append(truth[ok])
        preds.append(pred[ok])
        actions.append(np.asarray(f.action_true)[ok])
    truth, pred, action = np.concatenate(truths), np.concatenate(preds), np.concatenate(actions)
    err = (pred - truth) ** 2
    total = err.sum()
    print(f"{args.model}: {truth.size} frames, progress MSE {err.mean():.4f}")
    print("label       frames  mean prediction  MSE     share of squared error")
    bins = np.minimum((truth * 10).astype(int), 9)
    for b in range(10):
        rows = bins == b
        if not rows.any():
            continue
        print(
            f"{b / 10:.1f}-{(b + 1) / 10:.1f}  {rows.mean():7.1%}  {pred[rows].mean():15.2f}  "
            f"{err[rows].mean():.4f}  {err[rows].sum() / total:10.1%}"
        )
    ends = (truth < ENDS[0]) | (truth > ENDS[1])
    print(f"\nat the ends (label < {ENDS[0]} or > {ENDS[1]}) and in between, per action")
    print("action             frames  MSE     ends: frames  MSE     share of error  between: MSE")
    for a in sorted(set(action.tolist())):
        rows = action == a
        e, m = err[rows], ends[rows]
        between = f"{e[~m].mean():.4f}" if (~m).any() else "-"
        print(
            f"{contract.ACTIONS[a]:17s} {rows.sum():7d}  {e.mean():.4f}  {m.mean():11.1%}  "
            f"{e[m].mean():.4f}  {e[m].sum() / e.sum():14.1%}  {between}"
        )
    print(
        f"all               {truth.size:7d}  {err.mean():.4f}  {ends.mean():11.1%}  "
        f"{err[ends].mean():.4f}  {err[ends].sum() / total:14.1%}  {err[~ends].mean():.4f}"
    )
    if args.show is not None:
        shown = np.flatnonzero(action == contract.ACTIONS.index(args.show))[args.first :][:60]
        print(f"\n{args.show}, its pooled frames {args.first} on")
        print("label      " + " ".join(f"{x:.2f}" for x in truth[shown]))
        print("prediction " + " ".join(f"{x:.2f}" for x in pred[shown]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
