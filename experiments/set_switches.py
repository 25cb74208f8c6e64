"""Where the labels of a session turn from a repeated action to standing, and how long the
model takes to follow: pauses inside a set against the ends of sets.

    python experiments/set_switches.py SESSION... [--model models/scotti-default.onnx]

Each session file is replayed through the daemon's path as ``scotti eval`` does. At
every frame where the label turns from a repeated action to ``standing`` it reads:

- whether the set goes on after that standing (the same action is the next label:
  a pause inside the set) or not (the set's end);
- how many still frames the label kept in the set after the last movement
  (``STILL_SPEED_MPS`` on the labelled keypoints, the convention's "still");
- how many frames after the switch the model first said standing.

Why: the labelling convention keeps the first ``SET_EDGE_REST_S`` of a pause in the
set; until the still standing after a set's last movement kept the same second (for
``PAUSING_ACTIONS``), it kept what the recipe held, and a causal model, which cannot
tell the two apart before the pause's bound has passed, was late at every set end
(docs/generalisation.md, "Where a set ends").
"""

from __future__ import annotations

import argparse
import statistics
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt
from common import ROOT, from_root, table
from scotti.evaluation.errors import EvaluationError
from scotti.evaluation.replay import replay_session
from scotti.firmware_protocol.errors import SessionError
from scotti.models.contract import (
    ACTIONS,
    FRAME_RATE_HZ,
    STANDING,
    STILL_SPEED_MPS,
    has_progress,
)
from scotti.models.errors import ModelError
from scotti.models.kv_streaming import open_step_model
from scotti.models.set_edges import frame_speeds

DEFAULT_MODEL = ROOT / "models" / "scotti-default.onnx"
PAUSE = "inside a set"
END = "set end"


@dataclass(frozen=True)
class Switch:
    """One frame where the label turns from a repeated action to standing."""

    action: str
    kind: str  # PAUSE or END
    kept_still: int | None  # still frames after the last movement still labelled the set
    # frames from the switch to the model's first standing; None: not while it lasted
    lag: int | None


def label_switches(truth: npt.ArrayLike, said: npt.ArrayLike, still: npt.ArrayLike) -> list[Switch]:
    """Every switch from a repeated action to standing in ``truth`` (N,) labels, with
    the model's ``said`` (N,) and the frames' ``still`` (N,) bools."""
    t, s, quiet = np.asarray(truth), np.asarray(said), np.asarray(still, dtype=bool)
    found = []
    for i in np.flatnonzero((t[1:] == STANDING) & (t[:-1] != STANDING)) + 1:
        action = int(t[i - 1])
        if not 0 <= action < len(ACTIONS) or not has_progress(action):
            continue
        after = np.flatnonzero(t[i:] != STANDING)
        resumes = after.size > 0 and int(t[i + after[0]]) == action
        run = int(after[0]) if after.size else len(t) - i  # the standing's frames
        moving = np.flatnonzero(~quiet[:i])
        standing = np.flatnonzero(s[i : i + run] == STANDING)  # said while it lasts
        found.append(
            Switch(
                ACTIONS[action],
                PAUSE if resumes else END,
                int(i - moving[-1] - 1) if moving.size else None,
                int(standing[0]) if standing.size else None,
            )
        )
    return found


def _range(values: list[int]) -> str:
    return f"{min(values)}-{max(values)}" if values else "-"


def markdown(switches: list[Switch], sessions: list[Path], model: Path) -> str:
    rows = []
    for action in dict.fromkeys(s.action for s in switches):
        for kind in (PAUSE, END):
            mine = [s for s in switches if s.action == action and s.kind == kind]
            if not mine:
                continue
            lags = [s.lag for s in mine if s.lag is not None]
            kept = [s.kept_still for s in mine if s.kept_still is not None]
            within = sum(lag <= 8 for lag in lags)
            never = len(mine) - len(lags)
            median = f"{statistics.median(lags):g}" if lags else "-"
            rows.append(
                [
                    f"`{action}`",
                    kind,
                    str(len(mine)),
                    _range(kept),
                    f"{median} ({_range(lags)})",
                    f"{within} of {len(mine)}",
                    str(never),
                ]
            )
    head = [
        "action",
        "switch to standing",
        "switches",
        "still frames the label kept after the last movement",
        "model's lag, frames: median (range)",
        "model within 8 frames",
        "standing over before the model said it",
    ]
    names = " ".join(from_root(p) for p in sessions)
    return (
        "\n".join([f"Model `{from_root(model)}`; sessions {names}:", "", *table(head, rows)]) + "\n"
    )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python experiments/set_switches.py",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("sessions", type=Path, nargs="+")
    p.add_argument("--model", type=Path, default=DEFAULT_MODEL)
    args = p.parse_args(argv)
    try:
        model = open_step_model(args.model)
        switches = []
        for path in args.sessions:
            frames = replay_session(path, model).frames
            still = frame_speeds(frames.pose_true, FRAME_RATE_HZ) < STILL_SPEED_MPS
            switches += label_switches(frames.action_true, frames.action_pred, still)
    except (ModelError, EvaluationError, SessionError, OSError) as exc:
        print(f"set_switches: {exc}", file=sys.stderr)
        return 1
    print(markdown(switches, args.sessions, args.model))
    return 0


if __name__ == "__main__":
    sys.exit(main())
