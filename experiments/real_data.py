"""Real recordings of other insoles, imported and scored per file: docs/real-data.md.

    python experiments/real_data.py                                  # the shipped model
    python experiments/real_data.py --model models/scotti-default.onnx \\
        --model runs/v13-p1-wide/models/scotti-ship.onnx --write docs/real-data.md

Each file of ``../shared/realdata`` (its README names sources and licences) is
imported by ``scotti import FILE -o data/realdata/NAME.scotti`` with no option
beyond what the file cannot say, then replayed through the daemon's path
(``evaluation.replay``) with each model. None of the files has labels; what the
person does is known from the sources (the table ``RECORDINGS`` below, with the
spans of quiet standing read off the force trace). Per file and model:

- still: the share of predictions for a time where both feet stayed on the
  ground for 1.5 s or more in a walking file (``still_slots``): not walking,
  and not known to be quiet standing, so scored as neither and never wrong;
- walking / standing: the share of predictions for a time in a walking
  (standing) span whose action is ``walking`` (``standing``), flagged or not;
  walking, published (pooled table): the share of walking predictions that
  say ``walking`` and go out without a withholding flag, what a subscriber
  acts on;
- out_of_range, unfamiliar: the share of predictions carrying that flag
  (models/ood.py); one-foot recordings must be out_of_range;
- confident wrong: the share of predictions at probability > 0.9 for an action
  other than the one the person does (running counts as walking), and the share
  of those that went out unflagged (what a robot would act on);
- steps /min: the person's cadence over the file, measured from the feet's
  loads as experiments/real_vs_sim_gait.py measures gait (the model's
  training walkers step 95-135 times a minute unless drawn with
  ``scotti sim corpus --paces wide``).

Goals (issue 37): walking >= 80 % of walking windows, standing >= 90 % of
standing windows, no confident exercise on any file.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import (
    ROOT,
    ExperimentError,
    run,
    scotti_command,
    write_between_markers,
    write_card_section,
)
from common import table as markdown_table

REALDATA = ROOT.parent / "shared" / "realdata"
DOC = ROOT / "docs" / "real-data.md"
DEFAULT_MODEL = ROOT / "models" / "scotti-default.onnx"
CARD = DEFAULT_MODEL.with_suffix(".card.md")  # the shipped model's card quotes its table
WORK = ROOT / "data" / "realdata"
CONFIDENT: Final = 0.9
STILL_S: Final = 1.5  # both feet on the ground this long: nobody walks there (still_slots)
UNSCORED: Final = -2  # truth where the person stands still in a walking file (not known)
BEGIN, END = "<!-- real-data:begin -->", "<!-- real-data:end -->"


@dataclass(frozen=True)
class Recording:
    """One real file and what the person does in it (seconds from its first frame)."""

    path: str  # under the realdata folder
    sensor: str
    activity: str  # walking | running | standing
    standing: tuple[tuple[float, float], ...] = ()  # spans of quiet standing
    one_foot: bool = False

    @property
    def name(self) -> str:
        return Path(self.path).name.split(".")[0]


RECORDINGS: Final = (
    Recording("pressure-r/pedar_example.asc", "novel pedar-x, 99 cells", "walking", ((0.0, 2.4),)),
    Recording("pressure-r/fscan_testL.asf", "Tekscan F-Scan, 60 x 21", "walking", one_foot=True),
    # Both feet, though the folder's README says left only (101 -LF and 101 -RF blocks);
    # 1.4 s: shorter than one window, so no prediction is made.
    Recording("pressure-r/xsensor_data.csv", "XSENSOR X4, 31 x 11", "running"),
    Recording("moticon-opengo/230927_102114.txt", "Moticon OpenGo, 16 cells", "walking"),
    Recording("moticon-opengo/230927_102137.txt", "Moticon OpenGo, 16 cells", "walking"),
    Recording("moticon-opengo/230927_102231.txt", "Moticon OpenGo, 16 cells", "walking"),
    Recording(
        "moticon-opengo/walk_data_with_events/text_export.txt",
        "Moticon OpenGo, 16 cells",
        "walking",
    ),
    *(
        Recording(f"physionet-gaitpdb/{name}_01.txt.gz", "gaitpdb, 8 sensors", "walking")
        for name in ("GaCo01", "GaCo02", "JuCo01", "JuCo02", "SiCo01", "GaPt03", "JuPt01", "SiPt02")
    ),
)


def import_file(rec: Recording, realdata: Path, work: Path) -> Path:
    """``scotti import`` the file once (kept in ``work``; remade when the source is newer)."""
    source = realdata / rec.path
    out = work / f"{rec.name}.scotti"
    if out.is_file() and out.stat().st_mtime >= source.stat().st_mtime:
        return out
    work.mkdir(parents=True, exist_ok=True)
    run(scotti_command("import", source, "-o", out, "--force"), work / "import.log")
    return out


def truth_at(rec: Recording, t: np.ndarray, still: np.ndarray | None = None) -> np.ndarray:
    """The action the person does at each time: walking (running) or standing.

    ``still`` (bool per time) marks where ``still_slots`` found no step: there
    the person does not walk, and what they do instead is not known
    (``UNSCORED``) unless a span of quiet standing says so.
    """
    from scotti.models.contract import ACTIONS

    moving = "walking"
    out = np.full(t.shape, ACTIONS.index(moving))
    if still is not None and rec.activity != "standing":
        out[still] = UNSCORED
    for a, b in rec.standing:
        out[(t >= a) & (t <= b)] = ACTIONS.index("standing")
    if rec.activity == "standing":
        out[:] = ACTIONS.index("standing")
    return out


def still_slots(session: Path) -> np.ndarray:
    """(N,) bool: slots in a stretch of ``STILL_S`` or more where both feet carry load.

    A walker lifts a foot every step (double support lasts 0.1-0.3 s in these
    files, docs/real-data.md); both feet on the ground for 1.5 s is not
    walking, whatever the file's source says the person does (Moticon's
    "some walking steps" end in 4 s of both feet loaded). Contact as
    experiments/real_vs_sim_gait.py counts it: a foot above 5 % of the
    body-weight proxy.
    """
    import real_vs_sim_gait as gait
    from scotti.export.data import load_session
    from scotti.models.contract import FRAME_RATE_HZ

    s = load_session(session, gait.CACHE)
    loads = gait.foot_loads(gait.loaded_kpa(s.frames))
    bw = float(np.median(loads.sum(axis=1)))
    both = (loads > gait.CONTACT * bw).all(axis=1)
    out = np.zeros(len(both), dtype=bool)
    for a, b in gait.runs_of(both, s.segment):
        if b - a >= round(STILL_S * FRAME_RATE_HZ):
            out[a:b] = True
    return out


def replay_file(session: Path, models: list[Path]) -> list[Any]:
    """``session`` replayed through each model on the daemon's path (one
    ``evaluation.replay.SessionReplay`` a model, in their order)."""
    from scotti.evaluation.replay import replay_session_models
    from scotti.models.kv_streaming import open_step_model

    runtimes = [open_step_model(m, threads=1) for m in models]  # either form of the model
    return list(replay_session_models(session, runtimes))


def score_file(
    rec: Recording, session: Path, models: list[Path], replays: list[Any] | None = None
) -> list[dict[str, Any]]:
    """One row per model; ``replays`` (``replay_file``'s) when the caller has them."""
    from scotti.models.contract import ACTIONS, FRAME_RATE_HZ
    from scotti.models.ood import withheld

    still = still_slots(session)
    if replays is None:
        replays = replay_file(session, models)
    rows = []
    walking, standing = ACTIONS.index("walking"), ACTIONS.index("standing")
    for model, replay in zip(models, replays, strict=True):
        made = replay.made
        if not made:
            rows.append({"file": rec.name, "model": label(model), "predictions": 0})
            continue
        ext = np.array([m.ext for m in made], dtype=np.int64)
        slots = ext - ext.min() + 40  # the first prediction is for frame T=40
        t = slots / FRAME_RATE_HZ
        truth = truth_at(rec, t, still[np.minimum(slots, len(still) - 1)])
        probs = np.stack([m.probs for m in made])
        action = probs.argmax(axis=1)
        confident = probs.max(axis=1) > CONFIDENT
        flagged = np.array([withheld(set(m.flags)) is not None for m in made])
        flags = [set(m.flags) for m in made]
        wrong = (action != truth) & (truth != UNSCORED)
        on_walk, on_stand = truth == walking, truth == standing
        seen = np.unique(action, return_counts=True)
        rows.append(
            {
                "file": rec.name,
                "model": label(model),
                "predictions": len(made),
                "still": _share(truth == UNSCORED),
                "walking_windows": int(on_walk.sum()),
                "walking": _share(action[on_walk] == walking),
                "walking_published": _share((action == walking)[on_walk] & ~flagged[on_walk]),
                "standing_windows": int(on_stand.sum()),
                "standing": _share(action[on_stand] == standing),
                "out_of_range": _share(np.array(["out_of_range" in f for f in flags])),
                "unfamiliar": _share(np.array(["unfamiliar" in f for f in flags])),
                "confident_wrong": _share(confident & wrong),
                "confident_wrong_unflagged": _share(confident & wrong & ~flagged),
                "actions": {ACTIONS[a]: int(n) for a, n in zip(*seen, strict=True)},
            }
        )
    return rows


def cadence_of(session: Path) -> float | None:
    """Steps a minute over the whole file (experiments/real_vs_sim_gait.py's measure).

    None where the file holds no 3 s of both feet (one foot, or too short).
    """
    import real_vs_sim_gait

    try:
        return real_vs_sim_gait.gait_of(session, None).cadence
    except ExperimentError:
        return None


def label(model: Path) -> str:
    """A model's name in the tables: its path from the repository, without .onnx."""
    path = model.resolve()
    shown = path.relative_to(ROOT) if path.is_relative_to(ROOT) else path
    return str(shown.with_suffix(""))


def _cadence(value: float | None) -> str:
    return "-" if value is None else f"{value:.0f}"


def _share(mask: np.ndarray) -> float | None:
    return float(mask.mean()) if mask.size else None


def _pct(value: float | None) -> str:
    return "-" if value is None else f"{100 * value:.0f} %"


def table(recordings: list[Recording], rows: list[dict[str, Any]], command: str) -> str:
    by_file = {r.name: r for r in recordings}
    models = list(dict.fromkeys(r["model"] for r in rows))
    header = ["file", "sensor", "does", "steps /min", "model", "windows", "still"]
    header += ["walking", "standing"]
    header += ["out_of_range", "unfamiliar", "confident wrong", "of which unflagged"]
    per_file = []
    for row in rows:
        rec = by_file[row["file"]]
        does = rec.activity + (" (one foot)" if rec.one_foot else "")
        if rec.standing:
            does += ", stands first"
        top = sorted(row.get("actions", {}).items(), key=lambda kv: -kv[1])[:2]
        shares = ["walking", "standing", "out_of_range", "unfamiliar", "confident_wrong"]
        per_file.append(
            [row["file"], rec.sensor, does, _cadence(row.get("cadence"))]
            + [row["model"], str(row["predictions"]), _pct(row.get("still"))]
            + [_pct(row.get(k)) for k in [*shares, "confident_wrong_unflagged"]]
            + [", ".join(f"{a} {n}" for a, n in top)]
        )
    lines = [f"Written by `{command}` on {time.strftime('%Y-%m-%d')}.", ""]
    lines += markdown_table([*header, "read as (most)"], per_file, "lllrlrrrrrrrrl")
    lines += ["", "Pooled over the files (both feet present), per model:", ""]
    pooled = []
    for model in models:
        mine = [r for r in rows if r["model"] == model and not by_file[r["file"]].one_foot]
        pooled.append(
            [
                model,
                _pooled(mine, "walking", "walking_windows"),
                _pooled(mine, "walking_published", "walking_windows"),
                _pooled(mine, "standing", "standing_windows"),
                _pooled(mine, "unfamiliar", "predictions"),
                _pooled(mine, "confident_wrong", "predictions"),
                _pooled(mine, "confident_wrong_unflagged", "predictions"),
            ]
        )
    header = ["model", "walking", "walking, published", "standing", "unfamiliar"]
    header += ["confident wrong", "unflagged"]
    lines += markdown_table(header, pooled, "lrrrrrr")
    return "\n".join(lines) + "\n"


def _pooled(rows: list[dict[str, Any]], key: str, weight: str) -> str:
    total = sum(r.get(weight, 0) for r in rows if r.get(key) is not None)
    if not total:
        return "-"
    return _pct(sum(r[key] * r[weight] for r in rows if r.get(key) is not None) / total)


def quotes_in_card(doc: Path | None, models: list[Path], chosen: list[Recording]) -> bool:
    """Whether the run writes docs/real-data.md for the shipped model on every file, the
    table its card quotes."""
    if doc is None or doc.resolve() != DOC.resolve() or len(chosen) != len(RECORDINGS):
        return False
    return [m.resolve() for m in models] == [DEFAULT_MODEL.resolve()]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python experiments/real_data.py",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--model", type=Path, action="append", default=[])
    parser.add_argument("--realdata", type=Path, default=REALDATA)
    parser.add_argument("--work", type=Path, default=WORK, help="imported session files")
    parser.add_argument("--only", nargs="*", default=[], help="files whose name has this")
    parser.add_argument("--json", type=Path, help="also write the rows here")
    parser.add_argument("--write", type=Path, help="replace the marked section of this doc")
    args = parser.parse_args(argv)
    models = args.model or [ROOT / "models" / "scotti-default.onnx"]
    command = "python experiments/real_data.py " + " ".join(
        argv if argv is not None else sys.argv[1:]
    )
    try:
        if not args.realdata.is_dir():
            raise ExperimentError(f"{args.realdata}: no such folder (see its README)")
        chosen = [r for r in RECORDINGS if not args.only or any(o in r.path for o in args.only)]
        rows: list[dict[str, Any]] = []
        for rec in chosen:
            session = import_file(rec, args.realdata, args.work)
            cadence = cadence_of(session)
            rows += [row | {"cadence": cadence} for row in score_file(rec, session, models)]
            print(json.dumps(rows[-1]), flush=True)
        text = table(chosen, rows, command.strip())
        print(text)
        if args.json:
            args.json.write_text(json.dumps(rows, indent=1) + "\n")
        if args.write:
            write_between_markers(args.write, text, BEGIN, END)
        if quotes_in_card(args.write, models, chosen):
            heading = "## Real recordings of other insoles (docs/real-data.md)"
            write_card_section(CARD, f"{heading}\n\n{text}", "real-data")
    except ExperimentError as exc:
        print(f"real_data: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
