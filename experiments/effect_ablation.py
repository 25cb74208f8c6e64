"""Which of the simulator's sensor effects a model's failure on one subject needs.

    python experiments/effect_ablation.py --subject 2 \\
        --model runs/v9-p2/models/scotti-ship.onnx [--every 4] [--write docs/evaluation.md]

Renders corpus subject N again (data/corpus7's seed and minutes per action;
``--minutes-per-action`` for a quick look) several times: with all of the
effects the ``realistic`` preset drew for that subject, with none, and with
each effect left out in turn. The motion, the insole and the feet are the same
in every copy (sim/corpus.py draws them apart from the effects), so the copies
differ by their effects alone. Each copy is scored with ``scotti eval --every
K --json``; the table gives accuracy, standing recall, the share of standing
frames read as squat, squat progress MSE and the unfamiliar share. An effect
whose removal brings the figures back to the clean copy's is one the failure
needs (``--leave-out EFFECT ...``: only those copies). Copies and reports go
to runs/ablation/subject-NNN/ and are reused when there (reports per model
and ``--every``). ``--write DOC`` puts
the table between ``<!-- ablation:begin -->`` and ``<!-- ablation:end -->``
of DOC.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path
from typing import Any

from common import RUNS, ExperimentError, run, scotti_command, table, utc_now, write_between_markers

BEGIN, END = "<!-- ablation:begin -->", "<!-- ablation:end -->"
CORPUS_SEED = 1  # data/corpus7/realistic: scotti sim corpus --seed 1
MINUTES_PER_ACTION = 4.0  # its --minutes-per-action


def copies(subject: int, minutes: float, leave_out: tuple[str, ...] = ()) -> dict[str, Any]:
    """Name -> the subject's scene with all its effects, none, and each one left out
    (only those named in ``leave_out`` when given)."""
    from scotti.sim.corpus import subject_scene
    from scotti.sim.subjects import draw_subjects

    person = draw_subjects(subject + 1, CORPUS_SEED)[subject]
    scene = subject_scene(
        subject, person, corpus_seed=CORPUS_SEED, minutes_per_action=minutes, effects="realistic"
    )
    out = {"all effects": scene, "no effects": scene.model_copy(update={"effects": []})}
    for effect in scene.effects:
        if leave_out and effect["name"] not in leave_out:
            continue
        kept = [e for e in scene.effects if e["name"] != effect["name"]]
        out[f"without {effect['name']}"] = scene.model_copy(update={"effects": kept})
    return out


def render(scene: Any, path: Path) -> Path:
    from scotti.sim.corpus import render_scene

    if not path.is_file():
        partial = path.with_suffix(".partial")
        render_scene(scene, partial, subject_id=scene.name)
        partial.replace(path)
    return path


def score(session: Path, model: Path, every: int) -> dict[str, Any]:
    # One report per copy, model and --every: scoring another model never overwrites
    # a report, nor is a report of another model taken for this one's.
    digest = hashlib.sha256(model.read_bytes()).hexdigest()[:12]
    out = session.with_name(f"{session.stem}.{digest}.every{every}.json")
    if not out.is_file():
        cmd = scotti_command("eval", session, "--model", model, "--every", str(every), "--json")
        out.write_text(run(cmd, session.with_suffix(".log")))
    return dict(json.loads(out.read_text()))


def row(name: str, report: dict[str, Any]) -> list[str]:
    m, per = report["metrics"], report["per_action"]
    confusion = report["confusion"]
    actions = confusion["actions"]
    standing = confusion["matrix"][actions.index("standing")]
    as_squat = standing[actions.index("squat")] / max(1, sum(standing))
    return [
        name,
        f"{100 * m['action_accuracy']:.2f}",
        f"{100 * per['standing']['action_accuracy']:.1f}",
        f"{100 * as_squat:.1f}",
        f"{per['squat']['progress_mse']:.4f}",
        f"{m['progress_mse']:.4f}",
        f"{100 * (report.get('ood') or {}).get('unfamiliar', 0.0):.2f}",
    ]


def markdown(rows: list[list[str]], command: str) -> str:
    header = [
        "copy of the subject",
        "accuracy (%)",
        "standing recall (%)",
        "standing read as squat (%)",
        "squat progress MSE",
        "progress MSE",
        "unfamiliar (%)",
    ]
    return "\n".join([f"Written by `{command}` ({utc_now()}).", "", *table(header, rows)]) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python experiments/effect_ablation.py",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--subject", type=int, required=True, help="corpus index: 2 for 002")
    parser.add_argument("--model", type=Path, required=True, help="a streaming step graph")
    parser.add_argument("--every", type=int, default=4, help="scotti eval --every")
    parser.add_argument("--minutes-per-action", type=float, default=MINUTES_PER_ACTION)
    parser.add_argument(
        "--leave-out", nargs="+", default=(), metavar="EFFECT", help="only these (default: each)"
    )
    parser.add_argument("--out", type=Path, help="default runs/ablation/subject-NNN")
    parser.add_argument("--write", type=Path, help="replace the marked section of this doc")
    args = parser.parse_args(argv)
    command = "python experiments/effect_ablation.py " + " ".join(
        argv if argv is not None else sys.argv[1:]
    )
    out = args.out or RUNS / "ablation" / f"subject-{args.subject:03d}"
    try:
        if not args.model.is_file():
            raise ExperimentError(f"{args.model}: no such model")
        out.mkdir(parents=True, exist_ok=True)
        rows = []
        for name, scene in copies(
            args.subject, args.minutes_per_action, tuple(args.leave_out)
        ).items():
            session = render(scene, out / (name.replace(" ", "-") + ".ses"))
            rows.append(row(name, score(session, args.model, args.every)))
        text = markdown(rows, command)
        if args.write:
            write_between_markers(args.write, text, BEGIN, END)
    except (ExperimentError, OSError, KeyError, ValueError) as exc:
        print(f"effect_ablation: {exc}", file=sys.stderr)
        return 1
    print(text, end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
