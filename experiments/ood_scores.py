"""Three ways to score ``unfamiliar``, on the same weights: the table in docs/ood.md.

    python experiments/ood_scores.py --write docs/ood.md

The shipped graphs' pooled vectors of the training and validation windows
their card names (``card.ood``: ``train_subjects``, ``held_out_subjects``;
the sessions under ``--sessions``) are measured once
(export/ood_calibration.py) and three statistics fitted on them
(models/ood.py):

- ``global``: one mean and covariance over every training window, the
  threshold at the 99th percentile of the validation windows' distances;
- ``nearest``: each action's mean, the covariance around those means, the
  distance to the nearest mean, one threshold (Lee et al. 2018);
- ``predicted``: the same means, the distance to the mean of the action the
  model names, over that action's own 99th percentile (what export fits).

Each goes into a copy of both graphs (``--work``); the copies are replayed
through the daemon's path: ``scotti eval`` of the held-out test people and of
sim/scenes/squat.toml and demo.toml (rendered once), and the real files of
experiments/real_data.py. It trains nothing; about 8 minutes on 2 cores.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any, Final

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import ROOT, ExperimentError, run, scotti_command, write_between_markers
from common import table as markdown_table

BEGIN, END = "<!-- ood-scores:begin -->", "<!-- ood-scores:end -->"
SCENES: Final = ("squat", "demo")
HELD_OUT: Final = tuple(f"subject-{n:03d}" for n in (5, 7, 10, 13, 14))


def fitted(model: Path, sessions: Path, cache: Path | None, max_windows: int) -> dict[str, Any]:
    """The three statistics, fitted on the windows the shipped card names."""
    from scotti.export.ood_calibration import Calibration, gather, measure
    from scotti.models.contract import ACTIONS
    from scotti.models.ood import fit
    from scotti.models.runtime import ScottiRuntime, window_graph_for

    graph = ScottiRuntime(window_graph_for(model), threads=2)
    card = graph.card.get("ood") or {}
    if not card.get("train_subjects"):
        raise ExperimentError(f"{model}: its card names no calibration subjects")
    split = {"train_subjects": card["train_subjects"], "test_subjects": card["held_out_subjects"]}
    request = Calibration((sessions,), max_windows=max_windows, cache_dir=cache)
    sets = gather({"split": split}, request)
    train = measure(graph, sets.train, max_windows)
    held = measure(graph, sets.held_out, max_windows)
    return {
        "global": fit(train.pooled, held.pooled),
        "nearest": fit(train.pooled, held.pooled, 99.0, train.actions, None, ACTIONS),
        "predicted": fit(train.pooled, held.pooled, 99.0, train.actions, held.predicted, ACTIONS),
    }


def write_copy(model: Path, stats: Any, out: Path) -> Path:
    """Both graphs of ``model`` under ``out`` with these statistics in their metadata."""
    import onnx
    from scotti.models.contract import META_OOD
    from scotti.models.runtime import window_graph_for

    out.mkdir(parents=True, exist_ok=True)
    target = out / model.name
    for source, dest in ((model, target), (window_graph_for(model), window_graph_for(target))):
        proto = onnx.load(str(source))
        for prop in proto.metadata_props:
            if prop.key == META_OOD:
                prop.value = stats.to_json()
        onnx.save(proto, str(dest))
    return target


def unfamiliar_share(sessions: list[Path], model: Path) -> float:
    """``scotti eval --json``: the share of predictions flagged unfamiliar."""
    text = run(scotti_command("eval", *sessions, "--model", model, "--processes", "2", "--json"))
    return float(json.loads(text)["ood"]["unfamiliar"])


def real_files(models: list[Path]) -> dict[str, dict[str, float]]:
    """Pooled over the real files with both feet: unfamiliar, confident wrong unflagged."""
    import real_data

    rows: list[dict[str, Any]] = []
    for rec in real_data.RECORDINGS:
        if rec.one_foot:
            continue
        session = real_data.import_file(rec, real_data.REALDATA, real_data.WORK)
        rows += real_data.score_file(rec, session, models)
    out = {}
    for model in models:
        mine = [r for r in rows if r["model"] == real_data.label(model) and r["predictions"]]
        n = sum(r["predictions"] for r in mine)
        out[real_data.label(model)] = {
            key: sum(r[key] * r["predictions"] for r in mine) / n
            for key in ("unfamiliar", "confident_wrong_unflagged")
        }
        worst = max(mine, key=lambda r: r["confident_wrong_unflagged"])
        out[real_data.label(model)]["worst_file"] = worst["confident_wrong_unflagged"]
        out[real_data.label(model)]["worst_name"] = worst["file"]
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python experiments/ood_scores.py", description=__doc__)
    p.add_argument("--model", type=Path, default=ROOT / "models" / "scotti-default.onnx")
    p.add_argument("--sessions", type=Path, default=ROOT / "data" / "corpus18")
    p.add_argument("--cache-dir", type=Path, default=ROOT / "data" / "cache18")
    p.add_argument("--max-windows", type=int, default=4000, help="per side, as export")
    p.add_argument("--work", type=Path, default=ROOT / "runs" / "ood-scores")
    p.add_argument("--write", type=Path, help="replace the marked section of this doc")
    args = p.parse_args(argv)
    command = "python experiments/ood_scores.py " + " ".join(sys.argv[1:] if argv is None else argv)
    try:
        held = [next(args.sessions.glob(f"*/{s}.ses"), None) for s in HELD_OUT]
        if any(h is None for h in held):
            raise ExperimentError(f"{args.sessions}: no session of {', '.join(HELD_OUT)}")
        cache = args.cache_dir if args.cache_dir.is_dir() else None
        statistics = fitted(args.model, args.sessions, cache, args.max_windows)
        copies = {
            name: write_copy(args.model, s, args.work / name) for name, s in statistics.items()
        }
        scenes = {}
        for scene in SCENES:
            scenes[scene] = args.work / "scenes" / f"{scene}.ses"
            if not scenes[scene].is_file():
                toml = ROOT / "sim" / "scenes" / f"{scene}.toml"
                scenes[scene].parent.mkdir(parents=True, exist_ok=True)
                run(scotti_command("sim", toml, "-o", scenes[scene], "--force"))
        real = real_files(list(copies.values()))
        rows = []
        for name, copy in copies.items():
            figures = [unfamiliar_share([h for h in held if h], copy)]
            figures += [unfamiliar_share([scenes[s]], copy) for s in SCENES]
            r = real[_label(copy)]
            rows.append(
                [name]
                + [f"{100 * f:.2f} %" for f in figures]
                + [
                    f"{100 * r['unfamiliar']:.0f} %",
                    f"{100 * r['confident_wrong_unflagged']:.1f} %",
                    f"{100 * r['worst_file']:.0f} % ({r['worst_name']})",
                ]
            )
            print(json.dumps(rows[-1]), flush=True)
        header = ["score", "held-out people (5)", "squat.toml", "demo.toml"]
        header += ["real files: flagged", "real: confident wrong, unflagged", "worst file"]
        lines = [f"Written by `{command.strip()}` on {time.strftime('%Y-%m-%d')}.", ""]
        lines += markdown_table(header, rows, "lrrrrrr")
        text = "\n".join(lines) + "\n"
        print(text)
        if args.write:
            write_between_markers(args.write, text, BEGIN, END)
    except ExperimentError as exc:
        print(f"ood_scores: {exc}", file=sys.stderr)
        return 2
    return 0


def _label(copy: Path) -> str:
    import real_data

    return real_data.label(copy)


if __name__ == "__main__":
    raise SystemExit(main())
