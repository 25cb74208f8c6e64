"""What the ``unfamiliar`` flag trades: right answers withheld against wrong ones sent.

    python experiments/flag_operating_points.py --model runs/X/models/scotti-ship.onnx \\
        --checkpoint runs/X/best.pt --sessions data/corpus21 --cache-dir data/cache21 \\
        [--write docs/ood.md]

A model trained through foreign insoles and at other tempi (``scotti train
--sensor-transfer/--tempo-stretch``) can have its flag's statistics and
threshold fitted on windows as recorded or drawn as it was trained
(export/calibration_draws.py), at any percentile. Each choice is one
operating point: this command fits them all on the same pooled vectors of
the windows the model's card names (training subjects for the statistics,
held-out ones for the threshold; their clean copies left out, as
scripts/train_wide.sh calibrates) and scores each on people that neither
training nor calibration saw (p1's test people, experiments/ood_scores.py's
HELD_OUT), read three ways: as recorded, drawn as trained (other seeds), and
every window through a drawn foreign insole. Per way: the share of
action-labelled windows answered right and published (not flagged), the share
answered wrong and sent unflagged, and of those the confident ones (top
probability > 0.9, experiments/real_data.py's CONFIDENT).

It replays nothing through the daemon (the window graph, as export
calibrates) and trains nothing; about 8 minutes and over 10 GiB of memory on
2 cores with data/corpus21 (every training session is decoded into memory,
as export does).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Final

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import ROOT, ExperimentError, table, utc_now, write_between_markers
from ood_scores import HELD_OUT

BEGIN, END = "<!-- flag-points:begin -->", "<!-- flag-points:end -->"
CONFIDENT: Final = 0.9
PERCENTILES: Final = (90.0, 95.0, 99.0)
SIDES: Final = ("recorded", "as trained")


@dataclass(frozen=True)
class Windows:
    """One set of windows through the window graph."""

    pooled: np.ndarray  # (n, E)
    labels: np.ndarray  # (n,) target action, negative for none
    predicted: np.ndarray  # (n,)
    confidence: np.ndarray  # (n,) top softmax probability


def through(graph: Any, sessions: Sequence[Any], n: int, draws: Any, side: int) -> Windows:
    """Up to ``n`` windows of ``sessions``, drawn by ``draws``, through ``graph``."""
    from scotti.export.ood_calibration import window_batches

    pooled, labels, logits = [], [], []
    for windows, actions in window_batches(sessions, n, draws, side):
        out = graph.run_windows(windows, batch_size=len(windows))
        pooled.append(out.pooled)
        labels.append(actions)
        logits.append(out.action_logits)
    z = np.concatenate(logits).astype(np.float64)
    p = np.exp(z - z.max(axis=1, keepdims=True))
    p /= p.sum(axis=1, keepdims=True)
    return Windows(np.concatenate(pooled), np.concatenate(labels), p.argmax(1), p.max(1))


def shares(stats: Any, w: Windows) -> dict[str, float]:
    """Of the action-labelled windows: right and published, wrong and unflagged (and
    confident)."""
    flagged = stats.score(w.pooled, w.predicted) > stats.threshold
    acted = w.labels >= 0
    n = max(int(acted.sum()), 1)
    right = (w.predicted == w.labels) & acted
    sent_wrong = (w.predicted != w.labels) & acted & ~flagged
    confident = w.confidence > CONFIDENT
    return {
        "published_right": float((right & ~flagged).sum() / n),
        "wrong_unflagged": float(sent_wrong.sum() / n),
        "confident_wrong_unflagged": float((sent_wrong & confident).sum() / n),
    }


def operating_points(
    train: dict[str, Windows], held: dict[str, Windows], judges: dict[str, Windows]
) -> list[dict[str, Any]]:
    """Every (statistics side, threshold side, percentile), scored on every judge set."""
    from scotti.models.contract import ACTIONS
    from scotti.models.ood import fit

    rows = []
    for stats_side in SIDES:
        for threshold_side in SIDES:
            for q in PERCENTILES:
                t, h = train[stats_side], held[threshold_side]
                stats = fit(t.pooled, h.pooled, q, t.labels, h.predicted, ACTIONS)
                rows.append(
                    {
                        "statistics": stats_side,
                        "threshold": threshold_side,
                        "percentile": q,
                        **{name: shares(stats, w) for name, w in judges.items()},
                    }
                )
    return rows


def pct(x: float) -> str:
    return f"{100 * x:.1f} %"


def markdown(rows: Sequence[dict[str, Any]], command: str) -> str:
    header = [
        "statistics", "threshold", "p",
        "recorded: published", "wrong sent",
        "as trained: published", "wrong sent",
        "foreign: published", "wrong sent", "confident wrong sent",
    ]  # fmt: skip
    body = []
    for r in rows:
        rec, drawn, foreign = r["recorded"], r["as trained"], r["foreign"]
        figures = (
            rec["published_right"], rec["wrong_unflagged"],
            drawn["published_right"], drawn["wrong_unflagged"],
            foreign["published_right"], foreign["wrong_unflagged"],
            foreign["confident_wrong_unflagged"],
        )  # fmt: skip
        body.append([r["statistics"], r["threshold"], f"{r['percentile']:g}", *map(pct, figures)])
    lines = [f"Written by `{command}` on {utc_now()}.", ""]
    return "\n".join(lines + table(header, body, "lllrrrrrrr")) + "\n"


def calibration_files(sessions: Path) -> tuple[Path, ...]:
    """The session files under ``sessions`` but the clean copies (``clean/``), as
    scripts/train_wide.sh calibrates: the same people without the effects."""
    files = sorted(
        f for f in sessions.rglob("*.ses") if "clean" not in f.relative_to(sessions).parts
    )
    if not files:
        raise ExperimentError(f"{sessions}: no session files")
    return tuple(files)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python experiments/flag_operating_points.py")
    p.add_argument("--model", type=Path, required=True, help="a calibrated export")
    p.add_argument("--checkpoint", type=Path, required=True, help="its training checkpoint")
    p.add_argument("--sessions", type=Path, default=ROOT / "data" / "corpus21")
    p.add_argument("--cache-dir", type=Path, default=ROOT / "data" / "cache21")
    p.add_argument("--max-windows", type=int, default=4000, help="per side, as export")
    p.add_argument("--judge-windows", type=int, default=6000)
    p.add_argument("--write", type=Path, help="replace the marked section of this doc")
    args = p.parse_args(argv)
    command = "python experiments/flag_operating_points.py " + " ".join(
        sys.argv[1:] if argv is None else argv
    )
    try:
        rows = measure_all(args)
    except ExperimentError as exc:
        print(f"flag_operating_points: {exc}", file=sys.stderr)
        return 2
    text = markdown(rows, command)
    print(text)
    if args.write:
        write_between_markers(args.write, text, BEGIN, END)
    return 0


def measure_all(args: argparse.Namespace) -> list[dict[str, Any]]:
    import torch
    from scotti.export.calibration_draws import InputDraws
    from scotti.export.data import load_session
    from scotti.export.ood_calibration import Calibration, gather
    from scotti.models.runtime import ScottiRuntime, window_graph_for

    graph = ScottiRuntime(window_graph_for(args.model), threads=2)
    card = graph.card.get("ood") or {}
    if not card.get("train_subjects"):
        raise ExperimentError(f"{args.model}: its card names no calibration subjects")
    ckpt = torch.load(args.checkpoint, map_location="cpu", weights_only=True)
    trained = InputDraws.from_options(ckpt.get("options"))
    if not trained.active:
        raise ExperimentError(f"{args.checkpoint}: trained without foreign insoles or tempi")
    split = {"train_subjects": card["train_subjects"], "test_subjects": card["held_out_subjects"]}
    sets = gather(
        {"split": split}, Calibration(calibration_files(args.sessions), cache_dir=args.cache_dir)
    )
    held_out = [next(args.sessions.glob(f"*/{s}.ses"), None) for s in HELD_OUT]
    if any(h is None for h in held_out):
        raise ExperimentError(f"{args.sessions}: no session of {', '.join(HELD_OUT)}")
    people = [load_session(h, args.cache_dir) for h in held_out if h is not None]
    n, recorded = args.max_windows, InputDraws()
    train = {"recorded": through(graph, sets.train, n, recorded, 0)}
    train["as trained"] = through(graph, sets.train, n, trained, 0)
    held = {"recorded": through(graph, sets.held_out, n, recorded, 1)}
    held["as trained"] = through(graph, sets.held_out, n, trained, 1)
    again = replace(trained, seed=101)  # the same draws, another generator
    foreign = InputDraws(1.0, 0.0, trained.tempo_range, 103)
    m = args.judge_windows
    judges = {
        "recorded": through(graph, people, m, recorded, 2),
        "as trained": through(graph, people, m, again, 2),
        "foreign": through(graph, people, m, foreign, 3),
    }
    return operating_points(train, held, judges)


if __name__ == "__main__":
    raise SystemExit(main())
