"""How much of the real walking a model publishes is its flag's calibration draw.

    python experiments/flag_threshold_noise.py --model models/scotti-default.onnx \\
        --model runs/X/models/scotti-ship.onnx [--windows 4000 40000] [--draws 200] \\
        [--sessions data/corpus21] [--write docs/ood.md]

The ``unfamiliar`` flag's per-action thresholds are the 99th percentile of the
distances of held-out windows the model calls that action (models/ood.py).
Every shipped card's were fitted on 4,000 of the held-out people's windows, so
an action's threshold was about its fifth largest distance among 300-500
windows (``scotti export --ood-held-out-windows`` now takes them all). This
command asks how much that draw alone moves what a subscriber gets on the real
recordings:

1. the model's own statistics (means and whitening, from its graph) and the
   held-out people its card names (found under ``--sessions``, the clean
   copies left out, as scripts/train_wide.sh calibrates);
2. per ``--windows`` N: the held-out windows thinned evenly to N (export's
   draw), thresholds fitted as export fits them (the card's thresholds come
   back at N = 4,000), then ``--draws`` bootstrap resamples of those windows,
   each with its thresholds refitted;
3. for each set of thresholds, the share of the real walking windows
   (experiments/real_data.py's files, truth and still ends; one-foot files
   left out) read as walking and sent without a withholding flag (the input
   checks' flags included).

The real files go through the window graph at every frame, not through the
daemon's replay, so the published share here is near real_data.py's, not
equal to it (each window starts where the file does; a replay's history does
not). The question is the spread, which the same windows answer for every
draw. The bootstrap resamples windows of the same few people, so the spread
between people is not in it: it is a floor on the noise, not its size.
About 5 minutes a model on 2 cores.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import real_data
from common import ROOT, ExperimentError, table, utc_now, write_between_markers

BEGIN, END = "<!-- flag-noise:begin -->", "<!-- flag-noise:end -->"
PERCENTILE: Final = 99.0  # export's --ood-percentile default, what every shipped card used
SEED: Final = 0


@dataclass(frozen=True)
class RealWindows:
    """One real walking file's windows through a model's window graph."""

    name: str
    walking: np.ndarray  # (n,) bool: the person walks there (real_data's truth)
    predicted: np.ndarray  # (n,) action index
    distances: np.ndarray  # (n, K) plain distance to each action's mean
    inputs_ok: np.ndarray  # (n,) bool: no input check flags the window


def unit_thresholds(stats: Any) -> Any:
    """The same statistics with every threshold 1: scores are plain distances."""
    from scotti.models.ood import ActionMeans, OodStats

    am = stats.action_means
    if am is None:
        msg = "the model's unfamiliar score has no per-action means (calibrated before 67dc5d1)"
        raise ExperimentError(msg)
    ones = np.ones(len(am.actions), np.float32)
    return OodStats(stats.mean, stats.whitening, 1.0, {}, ActionMeans(am.actions, am.means, ones))


def distances(stats: Any, pooled: np.ndarray) -> np.ndarray:
    """(n, E) pooled vectors -> (n, K) Mahalanobis distances to each action's mean."""
    from scotti.models.ood import _distances

    return _distances(unit_thresholds(stats), np.asarray(pooled, dtype=np.float64))


def fit_thresholds(d: np.ndarray, predicted: np.ndarray, actions: Sequence[int]) -> np.ndarray:
    """Per action, as models/ood.py's ``fit`` does: the percentile of the distances of the
    windows predicted as it, or of every window's nearest distance where too few are."""
    from scotti.models.ood import MIN_CLASS_WINDOWS

    out = np.full(len(actions), float(np.percentile(d.min(axis=1), PERCENTILE)))
    for row, a in enumerate(actions):
        own = d[predicted == a, row]
        if len(own) >= MIN_CLASS_WINDOWS:
            out[row] = float(np.percentile(own, PERCENTILE))
    return out


def published_share(files: Sequence[RealWindows], rows: np.ndarray, th: np.ndarray) -> float:
    """Of the real walking windows, read as walking and sent without a withholding flag."""
    from scotti.models.contract import ACTIONS

    walking = ACTIONS.index("walking")
    sent = total = 0
    for f in files:
        row = rows[f.predicted]  # -1 where the predicted action has no mean
        known = row >= 0
        own = f.distances[np.arange(len(row)), np.where(known, row, 0)]
        unflagged = known & (own <= th[np.where(known, row, 0)]) & f.inputs_ok
        sent += int(((f.predicted == walking) & unflagged & f.walking).sum())
        total += int(f.walking.sum())
    return sent / max(total, 1)


def real_windows(graph: Any, stats: Any, realdata: Path) -> list[RealWindows]:
    """Every both-feet walking file, a window ending at each of its frames."""
    from scotti.export.data import load_session
    from scotti.models import input_checks
    from scotti.models.contract import ACTIONS, FRAME_RATE_HZ, WINDOW

    out = []
    for rec in real_data.RECORDINGS:
        if rec.one_foot or rec.activity != "walking":
            continue
        session = real_data.import_file(rec, realdata, real_data.WORK)
        frames = load_session(session).frames.astype(np.float32)
        if len(frames) <= WINDOW:
            continue
        windows = np.lib.stride_tricks.sliding_window_view(frames, WINDOW, axis=0)[:-1]
        windows = np.ascontiguousarray(np.moveaxis(windows, -1, 1))  # (n, T, H, 2W)
        result = graph.run_windows(windows, batch_size=64)
        slots = np.arange(len(windows)) + WINDOW  # the time each window predicts
        still = real_data.still_slots(session)
        truth = real_data.truth_at(
            rec, slots / FRAME_RATE_HZ, still[np.minimum(slots, len(still) - 1)]
        )
        ok = np.array([not input_checks.check_window(w).flags for w in windows])
        out.append(
            RealWindows(
                rec.name,
                truth == ACTIONS.index("walking"),
                result.action_logits.argmax(axis=1),
                distances(stats, result.pooled),
                ok,
            )
        )
    return out


def held_out_sessions(card: dict[str, Any], sessions: Path) -> list[Path]:
    """The card's held-out people's session files under ``sessions`` (not the clean copies)."""
    names = card["ood"]["held_out_subjects"]
    found = {p.stem: p for p in sorted(sessions.rglob("*.ses")) if "clean" not in p.parts}
    missing = [n for n in names if n not in found]
    if missing:
        msg = f"no session file of {', '.join(missing)} under {sessions}"
        raise ExperimentError(msg)
    return [found[n] for n in names]


def measure_model(model: Path, args: argparse.Namespace) -> list[dict[str, Any]]:
    from scotti.export.data import load_session
    from scotti.export.ood_calibration import measure
    from scotti.models.contract import ACTIONS
    from scotti.models.runtime import ScottiRuntime

    graph = ScottiRuntime(model.with_name(model.stem + ".window.onnx"))
    stats = graph.ood
    if stats is None:
        msg = f"{model} has no unfamiliar score to look at"
        raise ExperimentError(msg)
    card = json.loads(model.with_name(model.stem + ".card.json").read_text())
    am = unit_thresholds(stats).action_means
    rows = am.row_of_action
    walking_row = list(am.actions).index(ACTIONS.index("walking"))
    files = real_windows(graph, stats, args.realdata)
    people = [load_session(p) for p in held_out_sessions(card, args.sessions)]
    rng = np.random.default_rng(SEED)
    out = []
    for n in args.windows:
        held = measure(graph, people, n)
        d = distances(stats, held.pooled)
        th = fit_thresholds(d, held.predicted, am.actions)
        drawn = []
        for _ in range(args.draws):
            pick = rng.integers(0, len(d), len(d))
            refitted = fit_thresholds(d[pick], held.predicted[pick], am.actions)
            drawn.append(published_share(files, rows, refitted))
        shares = np.array(drawn)
        out.append(
            {
                "model": real_data.label(model),
                "held_out_windows": len(d),
                "walking_held_out": int((held.predicted == ACTIONS.index("walking")).sum()),
                "walking_threshold": float(th[walking_row]),
                "card_walking_threshold": float(stats.action_means.thresholds[walking_row]),
                "published": published_share(files, rows, th),
                "draws": args.draws,
                "mean": float(shares.mean()),
                "sd": float(shares.std()),
                "p5": float(np.percentile(shares, 5)),
                "p95": float(np.percentile(shares, 95)),
            }
        )
        print(json.dumps(out[-1]), flush=True)
    return out


def markdown(rows: Sequence[dict[str, Any]], command: str) -> str:
    def pct(x: float) -> str:
        return f"{100 * x:.1f} %"

    header = ["model", "held-out windows (walking)", "walking threshold", "published",
              "resampled: mean, sd", "5-95 %"]  # fmt: skip
    body = [
        [
            r["model"],
            f"{r['held_out_windows']} ({r['walking_held_out']})",
            f"{r['walking_threshold']:.2f}",
            pct(r["published"]),
            f"{pct(r['mean'])}, {100 * r['sd']:.1f} points",
            f"{pct(r['p5'])}-{pct(r['p95'])}",
        ]
        for r in rows
    ]
    lines = [f"`{command}` ({utc_now()}, {rows[0]['draws']} resamples a row):", ""]
    return "\n".join([*lines, *table(header, body, "lrrrrr")]) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--model", type=Path, action="append", required=True)
    parser.add_argument("--windows", type=int, nargs="+", default=[4000, 40000])
    parser.add_argument("--draws", type=int, default=200)
    parser.add_argument("--sessions", type=Path, default=ROOT / "data" / "corpus21")
    parser.add_argument("--realdata", type=Path, default=real_data.REALDATA)
    parser.add_argument("--json", type=Path)
    parser.add_argument("--write", type=Path, help="put the table between the markers of DOC")
    args = parser.parse_args(argv)
    try:
        rows = [r for m in args.model for r in measure_model(m, args)]
    except ExperimentError as e:
        print(f"flag_threshold_noise: {e}", file=sys.stderr)
        return 2
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    command = "python experiments/flag_threshold_noise.py " + " ".join(
        f"--model {m}" for m in args.model
    )
    text = markdown(rows, command)
    print(text)
    if args.write:
        write_between_markers(args.write, text, BEGIN, END)
    return 0


if __name__ == "__main__":
    sys.exit(main())
