"""How long the model goes on naming a set after the set has ended.

    python experiments/set_end_latency.py [--people 3] [--seconds 12] [--stand-s 6]
        [--model M] [--write docs/generalisation.md]

For every action with repetitions (models/contract.py ``has_progress``) and each of
``--people`` simulated people (drawn as the coverage grid draws them), a script
scene does the action for ``--seconds`` and then stands still for ``--stand-s``;
the session is replayed through the daemon's path, as ``scotti eval`` does, with
the shipped model (or ``--model``). Per person it reads, frame by frame:

- where the label turns from the set to ``standing`` (the labelling convention:
  at most ``SET_EDGE_REST_S`` of still standing after the last movement stays
  in the set, exactly that for squat and lunge) and how many frames after that
  the model first says standing;
- the same counted from the last movement of the set (no keypoint faster than
  ``STILL_SPEED_MPS``, the convention's "still"), and how much still standing
  the labels keep in the set after that movement, beside the
  ``SET_EDGE_REST_S`` a pause inside the set keeps;
- the longest still stretch inside the set's label (the convention keeps at
  most ``SET_EDGE_REST_S`` of a pause in the set; beyond it the pause is
  standing);
- how many of the wrong frames are the standing after the set.

Why: a causal model can only call a set over once the stillness is longer than
the pauses it was taught to call part of a set. Under the old convention (a
pause of any length was the set) the shipped model waited 1.4-2.1 s after squat
and lunge sets, and every error of `sim/scenes/squat.toml` was there; the table
says how long it takes for each action now (docs/generalisation.md).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from common import ROOT, from_root, table, utc_now, write_section
from coverage_grid import Cell, people
from scotti.evaluation.replay import replay_session
from scotti.models.contract import ACTIONS, NO_ACTION, STANDING, STILL_SPEED_MPS, has_progress
from scotti.models.errors import ModelError
from scotti.models.kv_streaming import StepModel, open_step_model
from scotti.models.set_edges import frame_speeds
from scotti.sim.corpus import render_scene
from scotti.sim.scene import Scene

DEFAULT_MODEL = ROOT / "models" / "scotti-default.onnx"
RATE_HZ = 16.0
SECTION = "set-end-latency"


@dataclass(frozen=True)
class SetEnd:
    """One person's set of one action and the still standing after it."""

    action: str
    standing_frames: int  # frames labelled standing after the set (scored ones)
    lag_frames: int | None  # from the label's switch to the first standing prediction
    lag_from_still: int | None  # the same from the set's last movement
    kept_still: int | None  # still frames after the last movement still labelled the set
    longest_pause: int  # the longest still run inside the set's label, in frames
    wrong: int = 0  # scored frames with an action label whose action is wrong
    wrong_after: int = 0  # of them, the standing frames after the set


def set_end(action: str, scene: Scene, model: StepModel, workdir: Path) -> SetEnd:
    """Render, replay and read one person's set end."""
    path = workdir / f"{scene.name}.ses"
    render_scene(scene, path, subject_id=scene.name)
    frames = replay_session(path, model).frames
    path.unlink()
    truth, said = frames.action_true, frames.action_pred
    index = ACTIONS.index(action)
    in_set = np.flatnonzero(truth == index)
    after = np.zeros(0, np.int64)
    if in_set.size:
        after = np.flatnonzero((truth == STANDING) & (np.arange(len(truth)) > in_set[-1]))
    if after.size == 0:
        msg = f"{scene.name}: no set followed by standing among the scored frames"
        raise ModelError(msg)
    switch = int(after[0])
    standing_said = np.flatnonzero((said == STANDING) & (np.arange(len(said)) >= switch))
    first = int(standing_said[0]) if standing_said.size else None
    still = frame_speeds(frames.pose_true, RATE_HZ) < STILL_SPEED_MPS
    moving = np.flatnonzero(~still[: switch + 1])
    last_move = int(moving[-1]) if moving.size else None
    labelled = truth != NO_ACTION  # transitions are not scored
    wrong = labelled & (said != truth)
    return SetEnd(
        action,
        int(after.size),
        None if first is None else first - switch,
        None if first is None or last_move is None else first - last_move,
        None if last_move is None else switch - last_move - 1,
        _longest_run(
            still[in_set[0] : in_set[-1] + 1] & (truth[in_set[0] : in_set[-1] + 1] == index)
        ),
        int(wrong.sum()),
        int(wrong[after].sum()),
    )


def _longest_run(flags: np.ndarray) -> int:
    """The longest run of True in a 1-D bool array."""
    best = run = 0
    for f in flags.tolist():
        run = run + 1 if f else 0
        best = max(best, run)
    return best


def markdown(results: list[SetEnd], args: argparse.Namespace, model: Path) -> str:
    rows = []
    for action in dict.fromkeys(r.action for r in results):
        mine = [r for r in results if r.action == action]
        lags = [r.lag_frames for r in mine if r.lag_frames is not None]
        from_still = [r.lag_from_still for r in mine if r.lag_from_still is not None]
        kept = [r.kept_still for r in mine if r.kept_still is not None]
        never = sum(r.lag_frames is None for r in mine)
        rows.append(
            [
                f"`{action}`",
                str(len(mine)),
                _frames_and_s(lags),
                _frames_and_s(from_still),
                _frames_and_s(kept),
                f"{max(r.longest_pause for r in mine) / RATE_HZ:.1f} s",
                f"{sum(r.wrong_after for r in mine)} of {sum(r.wrong for r in mine)}",
                str(never),
            ]
        )
    head = [
        "action",
        "people",
        "model names the set after its label ends: median (max) frames, s",
        "after its last movement",
        "still standing its label keeps after the last movement",
        "longest still pause inside a set",
        "wrong frames: standing after the set, of all",
        "never said standing",
    ]
    lines = [
        f"Model `{from_root(model)}`; {args.people} people an action (the coverage "
        f"grid's), {args.seconds:g} s of the action then {args.stand_s:g} s standing "
        f"still, every frame through the daemon's path; made {utc_now()}:",
        "",
        "```",
        f"python experiments/set_end_latency.py --people {args.people} "
        f"--seconds {args.seconds:g} --stand-s {args.stand_s:g}",
        "```",
        "",
        *table(head, rows),
    ]
    return "\n".join(lines) + "\n"


def _frames_and_s(values: list[int]) -> str:
    if not values:
        return "-"
    median = statistics.median(values)
    return f"{median:g} ({max(values)}); {median / RATE_HZ:.2f} s"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python experiments/set_end_latency.py",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--people", type=int, default=3)
    p.add_argument("--seconds", type=float, default=12.0, help="seconds of the action")
    p.add_argument("--stand-s", type=float, default=6.0, help="still standing after it")
    p.add_argument("--model", type=Path, default=DEFAULT_MODEL)
    p.add_argument("--write", type=Path, help="replace the doc's set-end-latency block")
    args = p.parse_args(argv)
    try:
        model = open_step_model(args.model)
        results = []
        with tempfile.TemporaryDirectory() as tmp:
            for action in (a for a in ACTIONS if has_progress(ACTIONS.index(a))):
                for person in people(args.people):
                    raw = Cell(action).scene(person, args.seconds)
                    raw["script"][0]["stand_s"] = args.stand_s
                    results.append(set_end(action, Scene.model_validate(raw), model, Path(tmp)))
                    r = results[-1]
                    print(f"{action} p{person.index}: lag {r.lag_frames} frames", file=sys.stderr)
    except ModelError as exc:
        print(f"set_end_latency: {exc}", file=sys.stderr)
        return 1
    text = markdown(results, args, args.model)
    print(text)
    if args.write:
        write_section(args.write, text, SECTION)
    return 0


if __name__ == "__main__":
    sys.exit(main())
