"""Ship an exported model as the daemon's default: models/scotti-default.* with its card.

    python scripts/ship_default.py runs/X/models/NAME.onnx [--int8] \\
        --eval runs/.../p1.json ... --data "what it was trained on" [--note "..."]

or, in one command from a training checkpoint (export with the unfamiliar
score calibrated, held-out evaluation, ship):

    python scripts/ship_default.py --checkpoint runs/X/best.pt \\
        --calibrate data/corpus/realistic --data "what it was trained on" [--every 4]

``--checkpoint`` runs ``scotti export CKPT -o runs/X/models/scotti-ship.onnx
--calibrate SESSIONS`` (statistics from the checkpoint's training subjects,
threshold from its held-out ones) and, unless ``--eval`` is given, ``scotti
eval --json`` on the held-out subjects' session files found among SESSIONS
(``--held-out SUBJECT ...``, or those the calibration held out);
then ships as below.

Copies the step and window graphs (the int8 copies with --int8) to
models/scotti-default.onnx and models/scotti-default.window.onnx, and writes
the model card: the export's card (config, parity proof, tools) plus what
was measured here: every held-out metric per partition with mean and spread,
per-frame latency of the streaming step (median and p99, batch 1, one and two
threads, this machine), FLOPs per frame, sizes and sha256. The card is also
embedded in both graphs (metadata ``scotti.card``), which is what the daemon
publishes on its ``info`` topic.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import platform
import sys
from pathlib import Path
from typing import Any

import onnx
from scotti.export.card import ood_markdown
from scotti.models.contract import META_CARD
from scotti.models.kv_streaming import open_step_model

# The card's pieces (training history, graph measurements, run logging) are the ones
# the experiment drivers use for the docs, so a card and a doc say the same things.
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "experiments"))
from card_training import training_block, training_markdown
from common import (
    ROOT,
    ExperimentError,
    fmt,
    from_root,
    mean_sd,
    run,
    scoring,
    scotti_command,
    utc_now,
)
from measure import describe

MODELS = ROOT / "models"
NAME = "scotti-default"
KEYS = ("mpjpe_mm", "mpjae_deg", "action_accuracy", "progress_mse", "app")


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def evaluation_block(reports: list[dict[str, Any]], commands: list[str]) -> dict[str, Any]:
    per = [
        {
            "partition": r.get("partition"),  # set by the sweep: which partition scored it
            "model": from_root(r["model"]["path"]) if r.get("model") else None,
            "subjects": r["subjects"],
            "frames": r["metrics"]["frames"],
            **{k: r["metrics"][k] for k in KEYS},
            "random_baseline": r["random_baseline"],
            "flagged": r.get("ood"),  # share of predictions each OOD flag withheld
        }
        for r in reports
    ]
    subjects = [
        {"subject": s["subject"], "frames": s["evaluated"], **{k: s["metrics"][k] for k in KEYS}}
        for r in reports
        for s in r["sessions"]
    ]
    # Several reports: the spread over partitions; one: the spread over its subjects.
    over, spread = (per, "partitions") if len(per) > 1 else (subjects, "held-out subjects")
    summary = {}
    for k in KEYS:
        values = [p[k] for p in over if p[k] is not None]
        mean, sd = mean_sd(values)
        summary[k] = {"mean": mean, "sd": sd, "n": len(values)}
    # Per action, pooled over every report: accuracy is each action's recall; standing
    # is scored like any action, its progress is not labelled (NaN, left out).
    per_action = {}
    for name in reports[0]["per_action"]:
        rows = [r["per_action"][name] for r in reports]
        frames = sum(int(row["frames"]) for row in rows)
        hits = sum(
            row["action_accuracy"] * row["frames_action"]
            for row in rows
            if row["frames_action"] and row["action_accuracy"] is not None
        )
        labelled = sum(int(row["frames_action"]) for row in rows)
        per_action[name] = {
            "frames": frames,
            "action_accuracy": hits / labelled if labelled else None,
        }
    every = max(int(r.get("every", 1)) for r in reports)
    how = (
        "scotti eval: held-out subjects' session files replayed through the daemon's "
        "streaming path; frames t-T..t-1 predict t"
    )
    if every > 1:
        how += f"; {scoring(every)}"
    return {
        "how": how,
        "every": every,
        "partitions": per,
        "per_subject": subjects,
        "summary": summary,
        "per_action": per_action,
        "spread_over": spread,
        "commands": commands,
    }


def _flagged(shares: dict[str, Any]) -> str:
    names = ("unloaded", "out_of_range", "unfamiliar")
    return "flagged " + ", ".join(f"{k} {100 * (shares.get(k) or 0):.2f} %" for k in names)


def card_md(card: dict[str, Any]) -> str:
    cfg = card["config"]
    ev = card.get("evaluation", {})
    lines = [
        f"# Model card: {card['name']}",
        "",
        f"{card['model']}. Contract version {card['contract_version']}; precision "
        f"{card['precision']}; {card['parameters']:,} parameters; shipped {card['shipped_utc']}.",
        "",
        f"Config: T={cfg['window']}, E={cfg['embed_dim']}, {cfg['layers']} transformer layers, "
        f"{cfg['heads']} heads, conv channels {cfg['conv_channels']}, head hidden "
        f"{cfg['head_hidden']}. Input: raw counts, left|right side by side; "
        f"normalisation in the graph: `{card['normalisation']}`. Timing: {card['timing']}.",
        "",
        "## Training data",
        "",
        card["shipped_data"],
        *training_markdown(card.get("training")),
        "",
        "## Held-out metrics (simulated subjects, not the paper's data)",
        "",
    ]
    if ev:
        over = ev["partitions"] if ev["spread_over"] == "partitions" else ev["per_subject"]
        # One model per partition (the same recipe on each): every line names its model.
        named = len({p.get("model") for p in ev["partitions"]}) > 1
        lines += [
            f"Mean ± standard deviation over {len(over)} {ev['spread_over']} (pooled figures "
            "per evaluation below)."
            + (
                " Each partition is scored with its own model (named below), trained on that "
                "partition's training subjects only; the shipped weights are one of them."
                if named
                else ""
            ),
            "",
            "| metric | value |",
            "|---|---|",
        ]
        scale = {
            "action_accuracy": (100.0, 2, " %"),
            "mpjpe_mm": (1.0, 1, " mm"),
            "mpjae_deg": (1.0, 2, " deg"),
            "progress_mse": (1.0, 4, ""),
            "app": (1.0, 4, ""),
        }
        for k in KEYS:
            s, d, unit = scale[k]
            lines.append(f"| {k} | {fmt([p[k] for p in over], d, s)}{unit} |")
        lines += [
            "",
            f"How: {ev['how']}.",
            "",
            *(
                f"- {p.get('partition') or 'held out'}"
                + (f" (model `{p['model']}`)" if named else "")
                + f": {', '.join(p['subjects'])} "
                f"({p['frames']} frames scored), pooled: MPJPE "
                f"{p['mpjpe_mm']:.1f} mm, MPJAE {p['mpjae_deg']:.2f} deg, accuracy "
                f"{100 * p['action_accuracy']:.2f} %, progress MSE {p['progress_mse']:.4f}, "
                f"APP {p['app']:.4f}; random baseline: accuracy "
                f"{100 * p['random_baseline']['action_accuracy']:.2f} %, APP "
                f"{p['random_baseline']['app']:.4f}"
                + (f"; {_flagged(p['flagged'])}" if p.get("flagged") else "")
                for p in ev["partitions"]
            ),
        ]
        if ev.get("per_action"):
            lines += [
                "",
                "Accuracy per true action (recall, pooled; `transition`: frames between "
                "actions, not scored):",
                "",
                "; ".join(
                    f"{name} {100 * row['action_accuracy']:.1f} % of {row['frames']}"
                    if row["action_accuracy"] is not None
                    else f"{name} - ({row['frames']} frames)"
                    for name, row in ev["per_action"].items()
                )
                + ".",
            ]
        lines += ["", "Commands:", "", "```", *ev["commands"], "```"]
    else:
        lines.append("Not evaluated.")
    lines += ood_markdown(card.get("ood"))
    lines += calibration_markdown(card.get("progress_calibration"))
    lat = card["latency"]
    lines += [
        "",
        "## Cost per frame (this machine)",
        "",
        f"Measured {lat['measured_utc']} on {lat['machine']}, batch 1, streaming step as the "
        "daemon calls it (`ScottiRuntime.step`; the streaming-native form's step on warm "
        "key/value caches):",
        "",
        "| threads | step median (ms) | step p99 (ms) | whole-window recompute median (ms) |",
        "|---|---|---|---|",
    ]
    for k, v in lat["by_threads"].items():
        lines.append(
            f"| {k} | {v['step_median_ms']:.2f} | {v['step_p99_ms']:.2f} | "
            f"{v['window_median_ms']:.2f} |"
        )
    lines += [
        "",
        f"FLOPs per frame: {card['flops']['step'] / 1e6:.1f} M (streaming step), "
        f"{card['flops']['window'] / 1e6:.1f} M (recomputing the window).",
        "",
        "## Files",
        "",
        *(
            f"- `{e['file']}`: {e['bytes'] / 1e6:.2f} MB, sha256 `{e['sha256']}`"
            for e in card["files"].values()
        ),
        "",
        f"Exported and proven against torch (atol {card['parity']['tolerance']['atol']:g}); "
        f"source checkpoint: `{card['shipped_from']}`.",
        "",
    ]
    if card.get("shipped_note"):
        lines += [card["shipped_note"], ""]
    return "\n".join(lines)


def calibration_markdown(info: dict[str, Any] | None) -> list[str]:
    """The card's words on the progress calibration (models/progress_calibration.py)."""
    if not info or not info.get("calibrated"):
        return ["", "## Progress calibration", "", "None: the progress head's output as it is."]
    s = info["summary"]
    return [
        "",
        "## Progress calibration",
        "",
        f"Progress goes through a monotone map per predicted action ({s['method']}), "
        f"fitted with `scotti calibrate` on the held-out validation subjects "
        f"{', '.join(s['fitted_on'])} ({sum(s['frames'].values())} frames; progress MSE "
        f"{s['mse_before']:.4f} -> {s['mse_after']:.4f} on them). The held-out figures "
        "above are of the calibrated model, on other subjects.",
    ]


def embed_card(src: Path, dst: Path, card: dict[str, Any]) -> None:
    proto = onnx.load(str(src))
    for prop in proto.metadata_props:
        if prop.key == META_CARD:
            prop.value = json.dumps(card, sort_keys=True)
            break
    else:
        entry = proto.metadata_props.add()
        entry.key, entry.value = META_CARD, json.dumps(card, sort_keys=True)
    onnx.save(proto, str(dst))


def export_calibrated(args: argparse.Namespace) -> Path:
    """``scotti export --calibrate``, then ``scotti eval`` on the held-out subjects."""
    # The verbs run from the repository root: paths as given here, made absolute.
    args.checkpoint = args.checkpoint.absolute()
    args.calibrate = [p.absolute() for p in args.calibrate]
    out = args.checkpoint.parent / "models" / "scotti-ship.onnx"
    export = ["export", args.checkpoint, "-o", out, "--calibrate", *args.calibrate]
    run(scotti_command(*export, "--cache-dir", args.cache_dir, "--force"))  # made again
    if args.eval:
        return out
    card = json.loads(out.with_name("scotti-ship.card.json").read_text())
    # The test subjects when the run held some out; a run whose only held-out
    # subjects were its validation split says them with --held-out.
    held = args.held_out or card["ood"]["held_out_subjects"]
    files = [
        p
        for p in sorted(f for d in args.calibrate for f in (d.glob("*.ses") if d.is_dir() else [d]))
        if p.stem in held
    ]
    report = args.checkpoint.parent / "eval" / "ship.json"
    report.parent.mkdir(parents=True, exist_ok=True)
    command = ["eval", *files, "--json", "--every", str(args.every)]
    report.write_text(run(scotti_command(*command, "--model", out)))
    args.eval = [str(report)]
    quoted = " ".join(
        from_root(a) if isinstance(a, Path) else str(a) for a in [*command[1:], "--model", out]
    )
    args.eval_command.append(f"scotti eval {quoted}")
    return out


def load_reports(specs: list[str]) -> list[dict[str, Any]]:
    """``[PARTITION=]REPORT`` -> the reports; a named partition's is its report's first model
    (partition_runs.py scores a second, uncalibrated copy beside it)."""
    reports = []
    for spec in specs:
        name, sep, path = spec.rpartition("=")
        value = json.loads(Path(path).read_text())
        listed = value if isinstance(value, list) else [value]
        reports += [listed[0] | {"partition": name}] if sep else listed
    return reports


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python scripts/ship_default.py", description=__doc__)
    parser.add_argument("model", type=Path, nargs="?", help="exported fp32 step graph (NAME.onnx)")
    parser.add_argument(
        "--checkpoint", type=Path, help="export this training checkpoint first (one command)"
    )
    parser.add_argument(
        "--calibrate", type=Path, nargs="+", default=[], help="with --checkpoint: sessions"
    )
    parser.add_argument("--every", type=int, default=1, help="with --checkpoint: scotti eval")
    parser.add_argument(
        "--held-out",
        nargs="+",
        default=[],
        metavar="SUBJECT",
        help="with --checkpoint: evaluate on these subjects (default: the calibration's)",
    )
    parser.add_argument("--cache-dir", type=Path, default=ROOT / "data" / "cache")
    parser.add_argument("--int8", action="store_true", help="ship the int8 copies")
    parser.add_argument(
        "--eval",
        nargs="+",
        action="extend",
        default=[],
        metavar="[PARTITION=]REPORT",
        help="scotti eval --json files; PARTITION= names the partition it scored "
        "(another partition's model: the card names it)",
    )
    parser.add_argument("--eval-command", action="append", default=[], help="quoted in the card")
    parser.add_argument("--data", required=True, help="what it was trained on, in words")
    parser.add_argument("--note", default="", help="one more paragraph for the card")
    parser.add_argument("--from", dest="source", default="", help="the checkpoint, for the card")
    parser.add_argument("--out-dir", type=Path, default=MODELS, help="where to ship (models/)")
    args = parser.parse_args(argv)
    if (args.model is None) == (args.checkpoint is None):
        parser.error("give either an exported MODEL or --checkpoint CKPT")
    if args.checkpoint is not None:
        if not args.calibrate:
            parser.error("--checkpoint needs --calibrate SESSIONS (training and held-out files)")
        try:
            args.model = export_calibrated(args)
        except ExperimentError as exc:
            print(f"ship_default: {exc}", file=sys.stderr)
            return 1
        args.source = args.source or str(args.checkpoint)

    base = args.model
    stem = base.name.removesuffix(".onnx")
    step = base.with_name(f"{stem}.int8.onnx") if args.int8 else base
    window = base.with_name(f"{stem}.int8.window.onnx" if args.int8 else f"{stem}.window.onnx")
    export_card = json.loads(base.with_name(f"{stem}.card.json").read_text())
    reports = load_reports(args.eval)

    measured = describe([step], [1, 2], steps=400)[str(step)]
    card = {k: v for k, v in export_card.items() if k not in ("files",)}
    card |= {
        "name": NAME,
        "precision": "int8 dynamic (MatMul/Gemm weights), Conv fp32" if args.int8 else "fp32",
        "shipped_utc": utc_now(),
        "shipped_from": args.source or str(base),
        "shipped_data": args.data,
        "shipped_note": args.note,
        "training": training_block(Path(args.source)) if args.source else None,
        "evaluation": evaluation_block(reports, args.eval_command) if reports else None,
        "latency": {
            "measured_utc": utc_now(),
            "machine": f"{platform.machine()}, {platform.processor() or 'cpu'}, 2 cores shared",
            "by_threads": measured["latency"],
        },
        "flops": {"step": measured["step_flops"], "window": measured["window_flops"]},
        "progress_calibration": open_step_model(step).progress_calibration_info(),
    }
    out = args.out_dir
    out.mkdir(parents=True, exist_ok=True)
    dst_step, dst_window = out / f"{NAME}.onnx", out / f"{NAME}.window.onnx"
    embed_card(step, dst_step, card)
    embed_card(window, dst_window, card)
    card["files"] = {
        kind: {"file": p.name, "bytes": p.stat().st_size, "sha256": _sha(p)}
        for kind, p in (("step", dst_step), ("window", dst_window))
    }
    (out / f"{NAME}.card.json").write_text(json.dumps(card, indent=2, sort_keys=True) + "\n")
    (out / f"{NAME}.card.md").write_text(card_md(card))
    runtime = open_step_model(dst_step)  # the daemon's own check: contract, graph, names
    print(f"shipped {dst_step} ({runtime!r}), card {out / NAME}.card.json")
    total = sum(e["bytes"] for e in card["files"].values())
    print(
        f"  {total / 1e6:.2f} MB in all; step p99 at 1 thread "
        f"{measured['latency']['1']['step_p99_ms']:.2f} ms"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
