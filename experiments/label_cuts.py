"""Where the stepping actions' repetition cuts fall against what the insoles show.

    python experiments/label_cuts.py [SESSIONS...] [--cache-dir data/cache] [--strike-share 0.3]

A cut the pressure maps mark (a foot landing) can be learnt to the frame; a cut
in the middle of single support can only be guessed from the time since the
last strike, and a model hedges there. For walking, side walking, walking in
place and walking backward, every run of the action in the sessions (default:
subject-000 of the realistic corpus) is cut three times: at the peaks of the
indicator of models/progress.py (the convention before 2026-12-01), at those of
its negative (its other extreme), and on the frame after each landing (the
convention in force, ``run_progress`` with ``step_cut="after_landing"``,
models/touchdown.py).
Each cut is compared with the nearest foot strike: the frame where a foot's
total count rises through ``--strike-share`` of its 95th percentile (0.3; 0.05
takes the first frame of load). Printed per action and cut: the cuts, the
median frames between cuts, and the offset to the nearest strike (mean and
spread, frames; negative = before the strike, which a causal model cannot yet
see).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from common import REALISTIC
from scotti.export.data import find_sessions, load_session
from scotti.models.contract import ACTIONS
from scotti.models.progress import PeakParams, progress_indicator, repetition_cuts, run_progress

STEPPING = ("walking", "side_walking", "in_place_walking", "backward_walking")
STRIKE_SHARE = 0.3  # of a foot's 95th-percentile total count


def strikes(load: np.ndarray, share: float = STRIKE_SHARE) -> np.ndarray:
    """Frames where either foot's total count rises through ``share`` of its p95."""
    found: list[int] = []
    for side in range(load.shape[1]):
        x = load[:, side] / max(float(np.percentile(load[:, side], 95)), 1.0)
        found += (np.flatnonzero((x[1:] >= share) & (x[:-1] < share)) + 1).tolist()
    return np.array(sorted(found), dtype=np.int64)


def runs(action: np.ndarray, wanted: int, shortest: int = 50) -> list[tuple[int, int]]:
    starts = np.flatnonzero(np.r_[True, action[1:] != action[:-1]])
    ends = np.r_[starts[1:], action.size]
    return [
        (s, e)
        for s, e in zip(starts, ends, strict=True)
        if action[s] == wanted and e - s >= shortest
    ]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python experiments/label_cuts.py", description=__doc__)
    parser.add_argument("sessions", nargs="*", type=Path)
    parser.add_argument("--cache-dir", type=Path)
    parser.add_argument("--strike-share", type=float, default=STRIKE_SHARE)
    args = parser.parse_args(argv)
    paths = find_sessions(args.sessions or [REALISTIC / "subject-000.ses"])
    print("action            sign       cuts  period  offset to strike: mean  spread (frames)")
    for name in STEPPING:
        a = ACTIONS.index(name)
        for label, sign in (("indicator", 1.0), ("negated", -1.0), ("after landing", 0.0)):
            offsets: list[int] = []
            periods: list[int] = []
            for path in paths:
                s = load_session(path, args.cache_dir)
                width = s.frames.shape[2] // 2
                load = np.stack(
                    [s.frames[:, :, :width].sum((1, 2)), s.frames[:, :, width:].sum((1, 2))], 1
                ).astype(np.float64)
                for start, end in runs(s.action, a):
                    if sign == 0.0:  # as the convention in force cuts it
                        params = PeakParams(step_cut="after_landing")
                        _, repetition = run_progress(s.keypoints[start:end], a, params)
                        cuts = np.flatnonzero(np.diff(repetition) > 0) + 1
                    else:
                        cuts = repetition_cuts(sign * progress_indicator(s.keypoints[start:end], a))
                    found = strikes(load[start:end], args.strike_share)
                    if found.size == 0:
                        continue
                    offsets += [int(c - found[np.argmin(np.abs(found - c))]) for c in cuts]
                    periods += np.diff(cuts).tolist()
            if not offsets:
                continue
            off = np.array(offsets, dtype=np.float64)
            print(
                f"{name:17s} {label:9s} {off.size:5d}  {np.median(periods):6.1f}"
                f"  {off.mean():+22.2f}  {off.std():6.2f}"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
