"""docs/accuracy-vs-latency.md: one table, one Pareto plot, and which model to pick."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from common import Partition, fmt, mean_sd, scoring, table
from tables_doc import kept_section

TASKS = (  # key, lower is better
    ("mpjpe_mm", True),
    ("action_accuracy", False),
    ("progress_mse", True),
    ("app", False),
)
KEYS = (*(k for k, _ in TASKS), "mpjae_deg")  # what a row carries per partition
SIZE_LIMIT_MB = 20.0
DAEMON_WINDOW = 40  # models.contract.WINDOW: the only T the daemon's runtime accepts


def _int8(step: Path) -> Path:
    return step.with_name(step.name.removesuffix(".onnx") + ".int8.onnx")


def _card(step: Path) -> dict[str, Any]:
    return dict(
        json.loads(step.with_name(step.name.removesuffix(".onnx") + ".card.json").read_text())
    )


def rows_of(
    models: dict[str, dict[str, Path]],
    timed: dict[str, Path],
    conv: dict[str, Path],
    plans: dict[str, dict[str, dict[str, Any]]],
    evaluated: dict[str, Any],
    latency: dict[str, Any],
) -> list[dict[str, Any]]:
    """One row per config and precision. ``models``: config -> partition -> fp32 step graph;
    ``timed``: config -> the step graph whose latency, size and card stand for the config;
    ``evaluated``: eval reports by step-graph path. Metrics are the mean over the partitions
    that have a report, ``spread`` their sample SD, ``n`` how many."""
    rows = []
    for name, fp32 in timed.items():
        card = _card(fp32)
        cfg = card["config"]
        runs = plans[name]
        variants = [("fp32", fp32, models[name]), ("int8", _int8(fp32), _int8s(models[name]))]
        if name in conv:
            variants.append(("int8+conv", conv[name], {}))  # latency only
        for precision, path, by_partition in variants:
            lat = latency[str(path)]
            reports = {
                part: evaluated[str(q)] for part, q in by_partition.items() if str(q) in evaluated
            }
            row: dict[str, Any] = {
                "label": f"{name} {precision}",
                "config": name,
                "precision": precision,
                "path": str(path),
                "paths": {part: str(q) for part, q in by_partition.items()},
                "E": cfg["embed_dim"],
                "layers": cfg["layers"],
                "T": cfg["window"],
                "parameters": card["parameters"],
                "size_mb": lat["bytes"] / 1e6,
                "step_mflops": lat["step_flops"] / 1e6,
                "window_mflops": lat["window_flops"] / 1e6,
                "latency": lat["latency"],
                "trained_min": mean_sd([r["trained_s"] / 60 for r in runs.values()])[0],
                "epochs": ", ".join(
                    f"{r.get('epochs_done', 0)}/{r['epochs']}" for r in runs.values()
                ),
                "stride": sorted({r["stride"] for r in runs.values()}),
                "n": len(reports),
                "metrics": None,
            }
            if reports:
                per = {part: {k: r["metrics"][k] for k in KEYS} for part, r in reports.items()}
                row["per_partition"] = per
                stats = {k: mean_sd([m[k] for m in per.values()]) for k in KEYS}
                row["metrics"] = {k: mean for k, (mean, _) in stats.items()}
                row["metrics"]["frames"] = sum(r["metrics"]["frames"] for r in reports.values())
                row["spread"] = {k: sd for k, (_, sd) in stats.items()}
            rows.append(row)
    return rows


def _int8s(models: dict[str, Path]) -> dict[str, Path]:
    return {part: _int8(path) for part, path in models.items()}


def _median(row: dict[str, Any], threads: int = 1) -> float:
    return float(row["latency"][str(threads)]["step_median_ms"])


def p99(row: dict[str, Any], threads: int = 1) -> float:
    return float(row["latency"][str(threads)]["step_p99_ms"])


def ranks(rows: list[dict[str, Any]]) -> dict[str, float]:
    """Mean rank over the four task metrics (1 = best) of the rows that have metrics."""
    scored = [r for r in rows if r["metrics"]]
    total = {r["label"]: 0.0 for r in scored}
    for key, lower in TASKS:
        order = sorted(scored, key=lambda r: r["metrics"][key] if lower else -r["metrics"][key])
        for i, r in enumerate(order):
            total[r["label"]] += (i + 1) / len(TASKS)
    return total


def choose_default(rows: list[dict[str, Any]], limit_ms: float) -> dict[str, Any] | None:
    """The most accurate (best mean rank) T=40 model under ``limit_ms`` p99 at one thread
    and at most SIZE_LIMIT_MB; ties go to the faster one."""
    rank = ranks(rows)
    fits = [
        r
        for r in rows
        if r["metrics"]
        and p99(r) < limit_ms
        and r["size_mb"] <= SIZE_LIMIT_MB
        and r["T"] == DAEMON_WINDOW  # the daemon runs T=40 models only
    ]
    if not fits:
        return None
    return min(fits, key=lambda r: (rank[r["label"]], p99(r)))


def _f(x: Any, digits: int, scale: float = 1.0) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    return f"{x * scale:.{digits}f}"


def _figure(row: dict[str, Any], key: str, digits: int, scale: float = 1.0) -> str:
    """``mean ± sd`` over the partitions (the mean alone for one), or a dash."""
    if not row["metrics"]:
        return "-"
    return fmt([p[key] for p in row["per_partition"].values()], digits, scale)


def write_sweep_doc(
    doc: Path,
    img: Path,
    *,
    rows: list[dict[str, Any]],
    choice: dict[str, Any] | None,
    limit_ms: float,
    partitions: list[Partition],
    every: int,
    share_min: float,
    invocation: str,
    commands: list[str],
    written: str,
) -> None:
    rank = ranks(rows)
    plot = pareto_plot(rows, img, limit_ms)
    body = []
    for r in rows:
        lat1, lat2 = r["latency"]["1"], r["latency"]["2"]
        body.append(
            [
                r["config"],
                r["precision"],
                str(r["E"]),
                str(r["layers"]),
                str(r["T"]),
                f"{r['size_mb']:.1f}",
                f"{r['step_mflops']:.0f}",
                f"{r['window_mflops']:.0f}",
                _figure(r, "mpjpe_mm", 1),
                _figure(r, "action_accuracy", 1, 100),
                _figure(r, "progress_mse", 4),
                _figure(r, "app", 4),
                str(r["n"]) if r["metrics"] else "-",
                f"{lat1['step_median_ms']:.2f} / {lat1['step_p99_ms']:.2f}",
                f"{lat2['step_median_ms']:.2f} / {lat2['step_p99_ms']:.2f}",
                f"{lat1['window_median_ms']:.2f}",
                f"{r['trained_min']:.1f} ({r['epochs']})",
                _f(rank.get(r["label"]), 1),
            ]
        )
    header = [
        "config",
        "precision",
        "E",
        "layers",
        "T",
        "size MB (step+window)",
        "MFLOPs/frame step",
        "MFLOPs/frame recompute",
        "MPJPE mm",
        "accuracy %",
        "progress MSE",
        "APP",
        "n",
        "step ms median / p99, 1 thread",
        "step ms, 2 threads",
        "recompute ms median, 1 thread",
        "trained min per run (epochs per partition)",
        "mean rank",
    ]
    lines = [
        "# What accuracy costs in time",
        "",
        *kept_section(doc),  # the current corpus's measurements, written by other commands
        f"Written by `{invocation}` ({written}). Every number was printed by the commands",
        "listed at the end, on this shared 2-core machine. Simulated subjects, not the paper's",
        "data (docs/evaluation.md has the paper's tables on the same partitions).",
        "",
        "## How it was measured",
        "",
        *method(partitions, every, share_min),
        "",
        *table(header, body),
        "",
        f"![accuracy against latency]({Path('img') / plot.name})",
        "",
        *findings(rows, limit_ms),
        "",
        "## Which model to pick",
        "",
        *advice(rows, choice, limit_ms),
        "",
        "## Commands",
        "",
        "```",
        "python experiments/corpus.py",
        invocation,
        *commands,
        "```",
        "",
    ]
    doc.parent.mkdir(parents=True, exist_ok=True)
    doc.write_text("\n".join(lines))


def method(partitions: list[Partition], every: int, share_min: float) -> list[str]:
    n, lead = len(partitions), partitions[0]
    return [
        f"- Partitions: {n} subject-wise partitions (`experiments/partitions.json`), each "
        f"{len(lead.train)} training and {len(lead.test)} held-out subjects:",
        *(f"  - {p.name}: held out {', '.join(p.test)}" for p in partitions),
        f"- Training: each config once on each partition's training subjects, {share_min:.1f}"
        " min of budget per run (the `trained min per run` column: the mean over the",
        "  partitions of the wall time of a run's `scotti train` calls, data loading and",
        "  validation included; epochs and window stride were planned from each config's",
        "  measured training throughput). **Every model here is undertrained**, the large ones",
        "  most of all: in the same minutes a wide model sees far fewer windows than a narrow",
        "  one. The accuracy columns compare what each config learns *in this budget*; with",
        "  hours of training the ordering of the wide models could change.",
        f"- Accuracy: `scotti eval` on each partition's {len(lead.test)} held-out subjects, "
        "replayed through the",
        f"  daemon's decoding, assembly and pairing, {scoring(every)}. Every figure is the",
        f"  **mean over the {n} partitions ± their sample SD** (`n`: partitions scored); each",
        "  partition's figure is pooled over its held-out subjects. int8 rows are the same",
        "  weights quantized (MatMul/Gemm, dynamic), scored the same way.",
        "- Latency: the streaming step graph, `ScottiRuntime.step` as the daemon calls it (one",
        "  new frame + the cached T-1 embeddings, batch 1), after a warm-up, models taking turns",
        f"  call by call, measured once per config and precision on its {lead.name} model (the",
        "  weights do not change the cost); `recompute` is one call of the window graph over",
        "  all T frames, what a non-streaming daemon would pay every frame. p99 on a machine",
        "  shared with other processes is an upper figure.",
        "- FLOPs: 2 x multiply-adds of the Conv/MatMul/Gemm nodes of the ONNX graphs.",
        "- `mean rank`: the mean of a model's ranks over the means of MPJPE, accuracy, progress",
        '  MSE and APP (1 = best); it is how "most accurate" is decided below.',
    ]


def findings(rows: list[dict[str, Any]], limit_ms: float) -> list[str]:
    out = ["## What the table shows", ""]
    by = {(r["config"], r["precision"]): r for r in rows}
    for (config, precision), r in by.items():
        if precision != "fp32":
            continue
        lat = r["latency"]["1"]
        gain = lat["window_median_ms"] / lat["step_median_ms"]
        line = (
            f"- {config}: streaming step {lat['step_median_ms']:.2f} ms against "
            f"{lat['window_median_ms']:.2f} ms to recompute the window ({gain:.1f}x)"
        )
        q = by.get((config, "int8"))
        if q:
            ql = q["latency"]["1"]
            line += f"; int8 step {ql['step_median_ms']:.2f} ms"
            if r["metrics"] and q["metrics"]:
                d_acc = 100 * (q["metrics"]["action_accuracy"] - r["metrics"]["action_accuracy"])
                d_mm = q["metrics"]["mpjpe_mm"] - r["metrics"]["mpjpe_mm"]
                line += f" (mean accuracy {d_acc:+.2f} points, MPJPE {d_mm:+.1f} mm against fp32)"
        c = by.get((config, "int8+conv"))
        if c:
            line += f"; with Conv quantized too {c['latency']['1']['step_median_ms']:.2f} ms"
        out.append(line + ".")
    return out


def advice(rows: list[dict[str, Any]], choice: dict[str, Any] | None, limit_ms: float) -> list[str]:
    rank = ranks(rows)
    scored = [r for r in rows if r["metrics"]]
    best = min(scored, key=lambda r: rank[r["label"]])
    fastest = min(scored, key=lambda r: p99(r))
    lines = []
    if choice is not None:
        lines.append(
            f"- **The default** (`models/scotti-default.onnx`): **{choice['label']}**, the most "
            f"accurate model here whose streaming step stays under {limit_ms:.0f} ms p99 on one "
            f"thread ({p99(choice):.2f} ms) and within {SIZE_LIMIT_MB:.0f} MB "
            f"({choice['size_mb']:.1f} MB); accuracy {_figure(choice, 'action_accuracy', 1, 100)} "
            f"%, MPJPE {_figure(choice, 'mpjpe_mm', 1)} mm over the partitions. Take it unless "
            "one of the needs below is yours."
        )
    else:
        lines.append(f"- No model met {limit_ms:.0f} ms p99 on one thread within the size limit.")
    lines.append(
        f"- **A small or busy host** (a robot's computer doing other work): "
        f"**{fastest['label']}**, the lowest p99 ({p99(fastest):.2f} ms at one thread), "
        f"{fastest['size_mb']:.1f} MB."
    )
    lines.append(
        f"- **Best figures regardless of cost**: **{best['label']}** (mean rank "
        f"{rank[best['label']]:.1f}; accuracy {_figure(best, 'action_accuracy', 1, 100)} %; "
        f"p99 {p99(best):.2f} ms at one thread, "
        f"{p99(best, 2):.2f} ms at two). At this training budget; a longer run is the first thing "
        "to try before paying for a wider model."
    )
    t20 = [r for r in scored if r["T"] == 20]
    if t20:
        lines.append(
            "- **Quick start after a gap**: a T=20 model would warm up in 20 frames (1.25 s) "
            f"instead of 40 (2.5 s): {t20[0]['label']}, at the accuracy the table shows. The "
            "daemon's contract fixes T=40 today, so it is measured here but cannot be shipped."
        )
    fp32 = [r for r in rows if r["precision"] == "fp32"]
    gains = {
        r["config"]: r["latency"]["1"]["step_median_ms"] / r["latency"]["2"]["step_median_ms"]
        for r in fp32
    }
    helped = [f"{c} {g:.2f}x" for c, g in gains.items() if g > 1.1]
    lines.append(
        "- **A spare core**: `threads = 2` in the daemon's model settings (step median, one "
        "thread against two): "
        + (", ".join(helped) if helped else "no config gained more than 10 %")
        + "; the others gain nothing worth a core."
    )
    by = {(r["config"], r["precision"]): r for r in rows}
    q = [(r, by[r["config"], "int8"]) for r in fp32 if (r["config"], "int8") in by]
    scored_pairs = [(a, b) for a, b in q if a["metrics"] and b["metrics"]]
    if scored_pairs:
        worst = max(
            abs(b["metrics"]["action_accuracy"] - a["metrics"]["action_accuracy"])
            for a, b in scored_pairs
        )
        speed = ", ".join(f"{a['config']} {_median(a) / _median(b):.1f}x" for a, b in q)
        lines.append(
            f"- **int8** (MatMul/Gemm): files about {q[0][0]['size_mb'] / q[0][1]['size_mb']:.1f}x "
            f"smaller, step faster by {speed} (one thread); accuracy moved by at most "
            f"{100 * worst:.2f} points in the mean over the partitions."
        )
    conv = [(by[c, "int8"], r) for (c, p), r in by.items() if p == "int8+conv"]
    for plain, both in conv:
        lines.append(
            f"- **int8 Conv too** ({plain['config']}): step {_median(both):.2f} ms "
            f"against {_median(plain):.2f} ms with fp32 Conv, window "
            f"recompute {both['latency']['1']['window_median_ms']:.2f} ms against "
            f"{plain['latency']['1']['window_median_ms']:.2f} ms: "
            + (
                "it does not pay, so Conv stays fp32."
                if both["latency"]["1"]["step_median_ms"] >= plain["latency"]["1"]["step_median_ms"]
                else "it pays here."
            )
        )
    return lines


def pareto_plot(rows: list[dict[str, Any]], img: Path, limit_ms: float) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    img.mkdir(parents=True, exist_ok=True)
    scored = [r for r in rows if r["metrics"]]
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2), dpi=120)
    for ax, key, label, scale in (
        (axes[0], "action_accuracy", "action accuracy (%)", 100.0),
        (axes[1], "mpjpe_mm", "MPJPE (mm, lower is better)", 1.0),
    ):
        configs = sorted({r["config"] for r in scored})
        colours = {c: f"C{i}" for i, c in enumerate(configs)}
        for r in scored:
            x, y = p99(r), r["metrics"][key] * scale
            sd = r.get("spread", {}).get(key, 0.0) * scale
            marker = "o" if r["precision"] == "fp32" else "s"
            ax.errorbar(
                [x],
                [y],
                yerr=[sd if math.isfinite(sd) else 0.0],
                fmt=marker,
                ms=6,
                capsize=2,
                lw=0.8,
                color=colours[r["config"]],
                label=r["label"],
            )
        lower = key == "mpjpe_mm"
        front, best = [], None
        for r in sorted(scored, key=p99):
            y = r["metrics"][key] * scale
            if best is None or (y < best if lower else y > best):
                best = y
                front.append((p99(r), y))
        if front:
            ax.step(
                *zip(*front, strict=True), where="post", color="grey", lw=1, label="Pareto front"
            )
        ax.axvline(limit_ms, color="red", ls="--", lw=1, label=f"{limit_ms:.0f} ms p99")
        ax.set_xscale("log")
        ax.set(xlabel="streaming step p99 (ms, 1 thread, log)", ylabel=label)
        ax.legend(fontsize=6, ncol=2)
    fig.suptitle(
        "Accuracy (mean ± SD over the partitions) against latency (circles fp32, squares int8)",
        fontsize=9,
    )
    fig.tight_layout()
    out = img / "accuracy-vs-latency.png"
    fig.savefig(out)
    plt.close(fig)
    return out
