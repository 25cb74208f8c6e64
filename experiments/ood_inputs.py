"""The figures behind the model's input checks and OOD flags (docs/ood.md).

    python experiments/ood_inputs.py [SESSIONS...] [--model models/scotti-default.onnx]
        [--held-out subject-005 ...] [--cache-dir data/cache] [--stride 1]

1. Every frame of the sessions (default: the realistic corpus) through
   ``models.input_checks.check_frame``: the nominal force per action (how far
   real standing and walking frames are above the ``unloaded`` threshold),
   the largest value of each ``out_of_range`` statistic, and the share of
   frames that break each rule and of windows the rules flag (should be 0).
2. Hard inputs through the model's window graph (onnxruntime): all zero,
   saturated, a single hot taxel, uniform noise, and real held-out windows
   with one foot zeroed, one foot's map mirrored (medial <-> lateral), or the
   feet swapped: the share of windows each flag catches.
"""

from __future__ import annotations

import argparse
import sys
from collections import defaultdict, deque
from pathlib import Path
from typing import Any

import numpy as np
from common import REALISTIC, ROOT
from scotti.export.data import find_sessions, load_session
from scotti.models import input_checks as ic
from scotti.models.contract import ACTIONS, FRAME_COLS, MAX_COUNT, NO_ACTION, WINDOW
from scotti.models.ood import UNFAMILIAR
from scotti.models.runtime import ScottiRuntime, window_graph_for

HELD_OUT = ("subject-005", "subject-007", "subject-010", "subject-013", "subject-014")  # p1 test


def corpus_figures(paths: list[Path], cache: Path | None, stride: int) -> dict[str, Any]:
    force_by_action: dict[str, list[float]] = defaultdict(list)
    foot_min = np.inf
    peaks = {"outside_share": 0.0, "rail_share": 0.0, "peak_share": 0.0, "force_n": 0.0}
    broken: dict[str, int] = defaultdict(int)
    frames = windows = 0
    flagged: dict[str, int] = defaultdict(int)
    for path in paths:
        s = load_session(path, cache)
        recent: deque[ic.FrameCheck] = deque(maxlen=WINDOW)
        segment = -1
        picked = range(0, len(s), stride)
        checks = [
            c for k in range(0, len(s), 4096) for c in ic.check_frames(s.frames[k : k + 4096])
        ]
        for i in picked:
            if s.segment[i] != segment:
                recent.clear()  # the daemon restarts its window at a long gap
                segment = int(s.segment[i])
            c = checks[i]
            recent.append(c)
            if len(recent) == WINDOW and stride == 1:
                windows += 1
                for flag in ic.verdict(recent).flags:
                    flagged[flag] += 1
            if not s.frame_ok[i]:
                continue  # a zero-filled foot: the daemon flags it degraded, not a real map
            frames += 1
            total = sum(c.force_n)
            action = int(s.action[i]) if s.has_label[i] else NO_ACTION
            force_by_action[ACTIONS[action] if action != NO_ACTION else "transition"].append(total)
            foot_min = min(foot_min, *c.force_n)
            peaks["outside_share"] = max(peaks["outside_share"], c.outside_share)
            peaks["rail_share"] = max(peaks["rail_share"], c.rail_share)
            peaks["peak_share"] = max(peaks["peak_share"], c.peak_share)
            peaks["force_n"] = max(peaks["force_n"], total)
            for rule in c.implausible:
                broken[rule] += 1
        print(f"  {path.name}: {len(s)} slots", file=sys.stderr)
    return {
        "frames": frames,
        "force_by_action": {
            k: np.percentile(v, [0, 0.1, 1, 50]).tolist()
            for k, v in sorted(force_by_action.items())
        },
        "foot_min_n": float(foot_min),
        "largest": peaks,
        "frames_breaking": dict(broken),
        "windows": windows,
        "windows_flagged": dict(flagged),
    }


def hard_inputs(model: Path, paths: list[Path], cache: Path | None) -> dict[str, dict[str, float]]:
    graph = ScottiRuntime(window_graph_for(model))
    shape = (WINDOW, *graph.frame_shape)
    real = []
    for path in paths:
        s = load_session(path, cache)
        for start in range(0, len(s) - WINDOW, 160):  # one window every 10 s
            if s.frame_ok[start : start + WINDOW].all():
                real.append(s.frames[start : start + WINDOW].astype(np.float32))
    base = np.stack(real)
    rng = np.random.default_rng(0)
    hot = np.zeros((1, *shape), np.float32)
    hot[:, :, 10, FRAME_COLS + 8] = MAX_COUNT
    left, right = np.s_[..., :FRAME_COLS], np.s_[..., FRAME_COLS:]
    cases = {
        "real held-out windows": base,
        "all zero": np.zeros((1, *shape), np.float32),
        "saturated": np.full((1, *shape), MAX_COUNT, np.float32),
        "single hot taxel": hot,
        "uniform noise": rng.uniform(0, MAX_COUNT, (20, *shape)).astype(np.float32),
    }
    for foot, cols in (("left", left), ("right", right)):
        zeroed = base.copy()
        zeroed[cols] = 0.0
        cases[f"{foot} foot zero"] = zeroed
        mirrored = base.copy()
        mirrored[cols] = base[cols][..., ::-1]
        cases[f"{foot} foot mirrored"] = mirrored
    cases["feet swapped"] = np.concatenate([base[right], base[left]], axis=-1)
    out = {}
    for name, w in cases.items():
        result = graph.run_windows(w)
        rules = [ic.check_window(x).flags for x in w]
        unfamiliar = result.unfamiliar
        flags = [
            (*r, *((UNFAMILIAR,) if u else ())) for r, u in zip(rules, unfamiliar, strict=True)
        ]
        row = {
            f: float(np.mean([f in fl for fl in flags]))
            for f in (ic.UNLOADED, ic.OUT_OF_RANGE, UNFAMILIAR)
        }
        row["any"] = float(np.mean([bool(fl) for fl in flags]))
        row["windows"] = len(w)
        row["finite"] = bool(
            np.isfinite(result.pose).all() and np.isfinite(result.action_probs).all()
        )
        out[name] = row
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python experiments/ood_inputs.py", description=__doc__)
    parser.add_argument("sessions", nargs="*", type=Path, default=[REALISTIC])
    parser.add_argument("--model", type=Path, default=ROOT / "models" / "scotti-default.onnx")
    parser.add_argument("--held-out", nargs="+", default=list(HELD_OUT), help="subjects (stems)")
    parser.add_argument("--cache-dir", type=Path, default=ROOT / "data" / "cache")
    parser.add_argument("--stride", type=int, default=1, help="every n-th frame (windows: n=1)")
    args = parser.parse_args(argv)
    paths = find_sessions(args.sessions)
    figures = corpus_figures(paths, args.cache_dir, args.stride)
    print(f"## Corpus: {len(paths)} sessions, {figures['frames']} frames (stride {args.stride})")
    print(
        "nominal force of both feet (N), min / p0.1 / p1 / median, vs unloaded < "
        f"{ic.UNLOADED_FORCE_N:g} N:"
    )
    for action, p in figures["force_by_action"].items():
        print(f"  {action:18s} " + " / ".join(f"{v:.0f}" for v in p))
    print(
        f"lightest single foot on any frame: {figures['foot_min_n']:.0f} N "
        f"(empty foot: < {ic.FOOT_EMPTY_N:g} N)"
    )
    big = figures["largest"]
    print(
        f"largest: outside share {big['outside_share']:.4f} (max {ic.OUTSIDE_SHARE_MAX}), "
        f"rail share {big['rail_share']:.4f} (max {ic.RAIL_SHARE_MAX}), peak share "
        f"{big['peak_share']:.3f} (max {ic.PEAK_SHARE_MAX}), force {big['force_n']:.0f} N "
        f"(max {ic.FORCE_MAX_N:g})"
    )
    print(f"frames breaking a rule: {figures['frames_breaking'] or 'none'}")
    print(f"windows flagged: {figures['windows_flagged'] or 'none'} of {figures['windows']}")
    held = [p for p in paths if p.stem in set(args.held_out)]
    if held and args.model.is_file():
        print(
            f"\n## Hard inputs through {args.model.name} (window graph), held out: "
            + ", ".join(p.stem for p in held)
        )
        print("| input | windows | unloaded | out_of_range | unfamiliar | any flag | finite |")
        print("|---|---|---|---|---|---|---|")
        for name, row in hard_inputs(args.model, held, args.cache_dir).items():
            print(
                f"| {name} | {row['windows']} | {100 * row['unloaded']:.1f} % | "
                f"{100 * row['out_of_range']:.1f} % | {100 * row['unfamiliar']:.1f} % | "
                f"{100 * row['any']:.1f} % | {row['finite']} |"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
