"""``scotti eval SESSIONS... [--model M] [--json] [--plots DIR]``: score a model like the paper.

Replays labelled session files through the daemon's own streaming path (see
``scotti.evaluation.evaluation``) as fast as the model runs, and prints MPJPE,
MPJAE, action accuracy and the confusion matrix, progress MSE and APP,
overall and per action, next to a random baseline. ``--plots DIR`` writes the
precision-margin curve and the confusion matrix as PNG files. ``--every K``
scores every K-th prediction time only, through the window graph next to each
model (NAME.window.onnx) in batches: a uniform sample for a fraction of the time.
Every prediction is made one way, batched streaming: ``--batch K`` (default
16) runs K segments of a session side by side in each step-graph call, the
same predictions as the daemon's window frame by frame (``--batch 1``), for
less CPU (a step costs 0.41 ms a frame at 16 frames a call, 1.10 alone:
docs/performance.md). ``--jobs J`` (default: the
cores the process may use) steps J such groups side by side on threads while
the next frames are decoded, again the same predictions (docs/evaluation.md,
"How fast it runs"). ``--decode process`` reads and decodes each session in a
process of its own beside those threads (``evaluation.decoded``; ``auto``, the
default, where it pays). ``--processes P`` replays whole sessions in P worker
processes instead (``evaluation.processes``): the Python between the model's
calls holds the interpreter's lock, so several sessions run faster on several
processes than on threads; the same report.
A streaming-native export (``scotti train --arch streaming``: its step graph says
``scotti.graph`` = ``step_kv``) is stepped through its own graph with a key/value
cache per segment (``evaluation.kv_segments``), the same report.

A session without labels (a live recording) has nothing to score: the report
says so in one line and gives what the model made of it (predictions, the
share each flag withheld, the actions it would have published, degraded
pairs, the rate), exit 0; in ``--json`` its figures are null. Labelled and
unlabelled files together: the labelled ones are scored, the others named.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path
from typing import Any, Final

from scotti.daemon.settings import ConfigError, default_model_path
from scotti.evaluation.evaluation import DECODE_CHOICES, EvaluationError, evaluate_models
from scotti.evaluation.segments import BATCH
from scotti.firmware_protocol.errors import SessionError
from scotti.firmware_protocol.overwrite import FORCE_HELP, refuse_existing
from scotti.firmware_protocol.session import find_session_files
from scotti.models.contract import ACTIONS
from scotti.models.errors import ModelError
from scotti.models.kv_streaming import open_step_model
from scotti.models.ood import format_flag_shares


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("sessions", nargs="+", type=Path, help="session files or directories")
    parser.add_argument(
        "--model",
        type=Path,
        action="append",
        help="streaming step graph (.onnx, either form); repeat it to score several models "
        "on one replay (default: the shipped model, as the daemon)",
    )
    parser.add_argument(
        "--json", action="store_true", help="print the report as JSON (a list for several models)"
    )
    parser.add_argument(
        "--plots",
        type=Path,
        default=None,
        help="write PNG figures here (DIR/MODEL/ for several); figures that exist are "
        "refused, unless --force",
    )
    parser.add_argument("--force", action="store_true", help=FORCE_HELP)
    parser.add_argument(
        "--threads", type=int, default=1, help="onnxruntime intra-op threads of each graph"
    )
    parser.add_argument(
        "--jobs",
        type=int,
        default=None,
        metavar="J",
        help="step each chunk's segments in J groups side by side on threads, the same "
        "predictions (default: the cores this process may use; 1: one thread)",
    )
    parser.add_argument(
        "--no-progress-calibration",
        action="store_true",
        help="score the progress head's output as it is, without the calibration the "
        "model carries (what it costs or buys: run both)",
    )
    parser.add_argument(
        "--processes",
        type=int,
        default=1,
        metavar="P",
        help="replay whole sessions in P worker processes, each on one thread (--jobs "
        "unused), the same report; several sessions on several cores run faster so "
        "than on threads (default 1: this process)",
    )
    parser.add_argument(
        "--decode",
        choices=DECODE_CHOICES,
        default="auto",
        help="read and decode each session here, or in a process of its own while this "
        "one steps the model, the same report (default auto: a process when --jobs > 1 "
        "and the sessions hold 64 MB or more; unused with --processes)",
    )
    parser.add_argument(
        "--every",
        type=int,
        default=1,
        metavar="K",
        help="score every K-th prediction time through the window graph in batches "
        "(default 1: every frame through the streaming step graph)",
    )
    parser.add_argument(
        "--batch",
        type=int,
        default=BATCH,
        metavar="K",
        help=f"step K segments of each session in one call of the step graph, the same "
        f"predictions as frame by frame (default {BATCH}, fewer for short sessions; "
        "1: frame by frame)",
    )


def run(args: argparse.Namespace) -> int:
    try:
        if args.threads < 1:
            msg = f"--threads must be at least 1, got {args.threads}"
            raise EvaluationError(msg)
        if args.every < 1:
            msg = f"--every must be at least 1, got {args.every}"
            raise EvaluationError(msg)
        if args.batch < 1:
            msg = f"--batch must be at least 1, got {args.batch}"
            raise EvaluationError(msg)
        jobs = usable_cores() if args.jobs is None else args.jobs
        if jobs < 1:
            msg = f"--jobs must be at least 1, got {jobs}"
            raise EvaluationError(msg)
        files = find_session_files(args.sessions)
        models = args.model or [default_model_path()]
        if args.plots is not None:  # before the replay: a refusal costs nothing
            refuse_existing(plot_paths(args.plots, models), force=args.force)
        calibrate = not args.no_progress_calibration
        runtimes = [
            open_step_model(m, threads=args.threads, calibrate_progress=calibrate) for m in models
        ]
        reports = evaluate_models(
            files,
            runtimes,
            every=args.every,
            batch=args.batch,
            jobs=jobs,
            processes=args.processes,
            decode=args.decode,
            on_session=_progress,
        )
        for report, runtime in zip(reports, runtimes, strict=True):
            report["model"]["ood"] = runtime.ood_info()
            report["model"]["progress_calibration"] = runtime.progress_calibration_info()
        if args.plots is not None and reports[0]["scored"]:  # no figure without labels
            for report in reports:
                where = args.plots if len(reports) == 1 else args.plots / _stem(report)
                report["plots"] = write_plots(report, where)
    except (EvaluationError, ModelError, SessionError, ConfigError, OSError) as exc:
        print(f"scotti eval: {exc}", file=sys.stderr)
        return 2
    print(rate_line(reports[0]["rate"]), file=sys.stderr)  # stdout stays the report
    if args.json:
        if not reports[0]["scored"]:  # the text report says it in its own lines
            print(f"scotti eval: {nothing_to_score(reports[0])}", file=sys.stderr)
        value = reports[0] if len(reports) == 1 else reports
        print(json.dumps(_finite(value), indent=2, allow_nan=False))
    else:
        print("\n\n".join("\n".join(format_report(r)) for r in reports))
    return 0


def usable_cores() -> int:
    """The cores this process may run on (its affinity, as a container or taskset sets it)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def rate_line(rate: dict[str, Any]) -> str:
    """How fast it went, one line on stderr."""
    return (
        f"scotti eval: {rate['paired_frames']} paired frames in {rate['seconds']:.2f} s "
        f"({rate['frames_per_s'] or 0:.0f} frames/s; CPU {rate['cpu_seconds']:.2f} s, "
        f"{rate['frames_per_cpu_s'] or 0:.0f} frames/s); "
        f"model {rate['model_cpu_seconds']:.2f} CPU s of it, "
        f"without the model {rate['without_model_frames_per_cpu_s'] or 0:.0f} frames per CPU s; "
        f"peak RSS {rate['peak_rss_mb']} MB; " + _workers(rate)
    )


def _workers(rate: dict[str, Any]) -> str:
    processes = rate.get("processes", 1)
    if processes > 1:
        return f"{processes} processes"
    where = " (decoded in a process of its own)" if rate.get("decode") == "process" else ""
    return f"{rate['jobs']} job(s){where}"


def _progress(done: int, total: int, path: Path, seconds: float) -> None:
    """One line per session on stderr (stdout stays the report, also with --json)."""
    if total > 1:
        print(f"scotti eval: {done}/{total} {path.name} ({seconds:.1f} s)", file=sys.stderr)


PLOTS: Final = ("precision-margin.png", "confusion.png")
LEGEND = (
    "  MPJPE: mean per-joint position error (mm); MPJAE: mean per-joint angle error (deg)\n"
    "  acc: action accuracy; MSE: progress mean squared error; APP: area under the progress\n"
    "  precision-margin curve (chance 2/3); -: nothing to score (no action, no progress)"
)


def _stem(report: dict[str, Any]) -> str:
    return _name(Path(report["model"]["path"]))


def _name(model: Path) -> str:
    return model.name.removesuffix(".onnx")


def nothing_to_score(report: dict[str, Any]) -> str:
    """The one line that says why no figure could be scored."""
    if len(report["unlabelled_sessions"]) == len(report["sessions"]):
        why = "no session has labels (label records)"
    else:
        why = "no prediction fell on a labelled frame (sessions shorter than the window?)"
    return f"nothing to score: {why}; reporting what the model made of them"


def format_report(report: dict[str, Any]) -> list[str]:
    m = report["metrics"]
    model = report["model"]
    lines = [
        f"model {model['path']} (T={model['window']}, E={model['embed_dim']}), "
        f"{len(report['sessions'])} sessions, {m['frames']} frames evaluated"
    ]
    if not report["scored"]:
        return [*lines, f"  {nothing_to_score(report)}", *_made_lines(report), *_tail(report)]
    lines.append(
        f"  MPJPE {_figure(m['mpjpe_mm'], '.2f')} mm   MPJAE {_figure(m['mpjae_deg'], '.2f')} "
        f"deg   accuracy {_figure(100 * m['action_accuracy'], '.2f')} %   "
        f"progress MSE {_figure(m['progress_mse'], '.4f')}   APP {_figure(m['app'], '.4f')}"
    )
    base = report["random_baseline"]
    lines.append(
        f"  random baseline: accuracy {_figure(100 * base['action_accuracy'], '.2f')} %   "
        f"progress MSE {_figure(base['progress_mse'], '.4f')}   "
        f"APP {_figure(base['app'], '.4f')}"
    )
    if report["unlabelled_sessions"]:
        lines.append(f"  not scored, no labels: {', '.join(report['unlabelled_sessions'])}")
    return lines + _made_lines(report) + _scored_lines(report) + _tail(report)


def _made_lines(report: dict[str, Any]) -> list[str]:
    """What the model made of the sessions, labels or not: timing, flags, actions."""
    lines = [
        f"  {report['predictions']} predictions from {report['pairs']} paired frames, "
        f"{report['degraded_pairs']} of them degraded (a foot held, filled or patched)"
    ]
    if "step_ms_per_row" in report:
        row = report["step_ms_per_row"]
        lines.append(
            f"  every prediction, batched streaming (the step graph) on up to "
            f"{row['largest_batch']} segments at a time: {row['mean']:.2f} ms per step row "
            "(throughput, not streaming latency)"
        )
    else:
        w = report["window_ms_per_prediction"]
        lines.append(
            f"  1 prediction in {report['every']}, window graph in batches of "
            f"{w['batch_size']}: {w['mean']:.2f} ms per scored window "
            "(throughput, not streaming latency)"
        )
    lines.append(format_flag_shares(report.get("ood"), report["model"].get("ood")))
    published = {k: n for k, n in report["actions_predicted"].items() if n}
    counts = ", ".join(f"{k} {n}" for k, n in sorted(published.items(), key=lambda kv: -kv[1]))
    lines.append(
        f"  actions published ({sum(published.values())} predictions; "
        f"{report['actions_withheld']} withheld by a flag): {counts or 'none'}"
    )
    return lines


def _scored_lines(report: dict[str, Any]) -> list[str]:
    """Per action, the confusion matrix and the plots: only when labels were scored."""
    lines = []
    lines.append(
        f"  {'action':18s} {'frames':>7s} {'MPJPE':>8s} {'acc %':>7s} {'MSE':>8s} {'APP':>7s}"
    )
    absent = []
    for name, row in report["per_action"].items():
        if not row["frames"]:
            absent.append(name)  # no frames: every figure would be nan
            continue
        lines.append(
            f"  {name:18s} {row['frames']:7d} {_cell(row['mpjpe_mm'], 8, '.2f')} "
            f"{_cell(100 * row['action_accuracy'], 7, '.2f')} "
            f"{_cell(row['progress_mse'], 8, '.4f')} {_cell(row['app'], 7, '.4f')}"
        )
    if absent:
        lines.append(f"  not in these sessions: {', '.join(absent)}")
    lines.append(LEGEND)
    lines.append("  confusion (rows true, columns predicted): " + " ".join(ACTIONS))
    for name, row in zip(ACTIONS, report["confusion"]["matrix"], strict=True):
        lines.append(f"  {name:18s} " + " ".join(f"{c:6d}" for c in row))
    return lines


def _tail(report: dict[str, Any]) -> list[str]:
    """Each session's counts, then the figures written."""
    lines = []
    for s in report["sessions"]:
        lines.append(
            f"  {s['path']}: {s['labels']} labels, {s['predictions']} predictions, "
            f"{s['evaluated']} scored, {s['window_restarts']} window restarts, "
            f"{s['degraded_pairs']} degraded pairs, {s['decode_errors']} decode errors"
        )
        for foot, n in s.get("silent_pairs", {}).items():
            if n:
                lines.append(
                    f"  {s['path']}: {foot} insole silent on {n} of {s['pairs']} pairs"
                    " (zero-filled: an insole off, or a one-foot recording; the model"
                    " never learnt one foot, its predictions there are not to be trusted)"
                )
    lines += [f"  wrote {path}" for path in report.get("plots", [])]
    return lines


def plot_paths(directory: Path, models: list[Path]) -> list[Path]:
    """Every figure ``--plots`` writes for these models (DIR/MODEL/ for several)."""
    folders = [directory] if len(models) == 1 else [directory / _name(m) for m in models]
    return [folder / name for folder in folders for name in PLOTS]


def write_plots(report: dict[str, Any], directory: Path) -> list[str]:
    """precision-margin.png and confusion.png (matplotlib, loaded only when asked)."""
    import matplotlib  # heavy and optional: only for --plots

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    directory.mkdir(parents=True, exist_ok=True)
    pm = report["precision_margin"]
    fig, ax = plt.subplots(figsize=(4.5, 3.5), dpi=120)
    ax.plot(pm["margins"], pm["precision"], label=f"model, APP {pm['app']:.3f}")
    m = [i / 100 for i in range(101)]
    chance = [1 - (1 - x) ** 2 for x in m]  # uniform guess against uniform labels: APP 2/3
    ax.plot(m, chance, "--", color="grey", label="random, uniform labels (APP 2/3)")
    ax.set(xlabel="margin", ylabel="precision", xlim=(0, 1), ylim=(0, 1.02))
    ax.set_title("Progress: precision-margin curve")
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    curve = directory / PLOTS[0]
    fig.savefig(curve)
    plt.close(fig)

    matrix = report["confusion"]["matrix"]
    fig, ax = plt.subplots(figsize=(6, 5), dpi=120)
    totals = [max(1, sum(row)) for row in matrix]
    shares = [[c / t for c in row] for row, t in zip(matrix, totals, strict=True)]
    image = ax.imshow(shares, vmin=0, vmax=1, cmap="Blues")
    ticks = range(len(ACTIONS))
    ax.set_xticks(ticks, ACTIONS, rotation=45, ha="right", fontsize=7)
    ax.set_yticks(ticks, ACTIONS, fontsize=7)
    for i, row in enumerate(shares):
        for j, v in enumerate(row):
            ax.text(j, i, f"{100 * v:.0f}", ha="center", va="center", fontsize=6,
                    color="white" if v > 0.5 else "black")  # fmt: skip
    ax.set(xlabel="predicted", ylabel="true")
    ax.set_title("Action confusion (% of true frames)")
    fig.colorbar(image, ax=ax, fraction=0.046)
    fig.tight_layout()
    confusion = directory / PLOTS[1]
    fig.savefig(confusion)
    plt.close(fig)
    return [str(curve), str(confusion)]


def _figure(value: float | None, spec: str) -> str:
    """A figure, or '-' when there is nothing to score (NaN: no frame of that kind)."""
    return _cell(value, 0, spec)


def _cell(value: float | None, width: int, spec: str) -> str:
    """A figure, or '-' right-aligned when there is nothing to score (NaN)."""
    if value is None or not math.isfinite(value):
        return "-".rjust(width)
    return f"{value:{width}{spec}}"


def _finite(value: Any) -> Any:
    """NaN becomes null: JSON has no NaN."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_finite(v) for v in value]
    return value
