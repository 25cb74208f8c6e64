"""docs/evaluation.md and its figures, from the ``scotti eval`` reports of paper_tables.py."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from common import Partition, fmt, mean_sd, table
from scotti.models.contract import NUM_ACTIONS

# Per-action rows that are not an action: transitions ("none" in reports before contract 2).
ROW_NAMES = {
    "none": "none (stand between actions)",
    "transition": "transition (between actions)",
}

KEEP_BEGIN, KEEP_END = "<!-- kept:begin -->", "<!-- kept:end -->"
PAPER = {"mpjpe_mm": 96.63, "action_accuracy": 0.9006, "app": 0.8952, "progress_mse": 0.0223}
METRICS = (  # key, column, digits, scale, lower is better
    ("mpjpe_mm", "MPJPE (mm)", 1, 1.0, True),
    ("mpjae_deg", "MPJAE (deg)", 2, 1.0, True),
    ("action_accuracy", "accuracy (%)", 2, 100.0, False),
    ("progress_mse", "progress MSE", 4, 1.0, True),
    ("app", "APP", 4, 1.0, False),
)
TASK_OF = {  # which single-task variant owns which metric
    "mpjpe_mm": "pose",
    "mpjae_deg": "pose",
    "action_accuracy": "action",
    "progress_mse": "progress",
    "app": "progress",
}


def by_variant(results: dict[str, list[dict[str, Any]]]) -> dict[str, list[dict[str, Any]]]:
    """variant -> its report on each partition, in partition order."""
    out: dict[str, list[dict[str, Any]]] = {}
    for reports in results.values():
        for r in reports:
            out.setdefault(r["variant"], []).append(r)
    return out


def values(reports: Sequence[dict[str, Any]], key: str, where: str = "metrics") -> list[float]:
    return [_num(r[where][key]) for r in reports]


def _num(x: Any) -> float:
    return float("nan") if x is None else float(x)


def write_evaluation_doc(
    doc: Path,
    img: Path,
    *,
    partitions: list[Partition],
    corpus: dict[str, Any],
    plans: dict[tuple[str, str], dict[str, Any]],
    results: dict[str, list[dict[str, Any]]],
    clean: dict[str, dict[str, Any]] | None = None,
    invocation: str,
    commands: list[str],
    written: str,
) -> None:
    v = by_variant(results)
    multi = v["multi"]
    img.mkdir(parents=True, exist_ok=True)
    confusion_png, curve_png = plot_confusion(multi, img), plot_curves(multi, img)
    rel = Path("img")
    lines = [
        "# Evaluation: SCOTTI on the simulated corpus, the paper's way",
        "",
        *kept_section(doc),
        f"Written by `{invocation}` ({written}); every number below was printed by",
        "`scotti eval` on the held-out subjects of each partition. **These are simulated",
        "subjects from `scotti sim corpus`, not the paper's recordings**: the figures show",
        "what our code does on our simulator, and compare with the paper only in structure.",
        "",
        "## Data and protocol",
        "",
        f"- Corpus: {corpus['subjects']} subjects drawn by the simulator (stature, mass, foot",
        f"  length, movement style), each doing all {NUM_ACTIONS} actions for "
        f"{corpus['minutes_per_action']}",
        f"  minutes per action; {corpus['total_hours']} hours in all, "
        f"corpus seed {corpus['seed']}.",
        f"  Effects (the simulator's `realistic` preset, drawn per subject): "
        f"{', '.join(corpus['effects'])}.",
        f"  Sessions in `{corpus['realistic']}`; the same subjects without effects in",
        f"  `{corpus['clean']}` (made by `python experiments/corpus.py`).",
        f"- {len(partitions)} subject-wise partitions of {len(partitions[0].train)} training and "
        f"{len(partitions[0].test)} test subjects, test sets disjoint",
        "  (`experiments/partitions.json`):",
        *(f"  - {p.name}: test {', '.join(p.test)}" for p in partitions),
        "- Each prediction is made from frames t-T..t-1 and scored against the label of",
        "  frame t, replaying the test session files through the daemon's own path",
        "  (decoder, frame assembler, pairing, streaming window with cached embeddings).",
        "- Every figure: mean over the three partitions ± sample standard deviation.",
        "  The models are the last checkpoint of each run (validation on the test",
        "  subjects is logged during training but never used to pick a checkpoint).",
        "",
        "## Training budget (read this before the numbers)",
        "",
        *budget_section(plans),
        "",
        "## Table 1: SCOTTI against a random progress baseline",
        "",
        *table1(multi, list((clean or {}).values())),
        "",
        "## Table 3: multi-task against single-task variants (same encoder)",
        "",
        *table3(v),
        "",
        "## Per action (multi-task model)",
        "",
        *per_action(multi),
        "",
        f"![confusion matrix, three partitions summed]({rel / confusion_png.name})",
        "",
        f"![precision-margin curves, one per partition]({rel / curve_png.name})",
        "",
        "## How this compares with the paper",
        "",
        *paper_comparison(multi),
        "",
        "## Commands",
        "",
        "```",
        "python experiments/corpus.py            # corpus + partitions",
        invocation,
        "```",
        "",
        "Each training, export and evaluation it ran (last invocation; training runs",
        "resumed from checkpoints show each call):",
        "",
        "```",
        *sorted({c for plan in plans.values() for c in plan.get("commands", [])}),
        *[c for c in commands if " train " not in c],
        "```",
        "",
    ]
    doc.parent.mkdir(parents=True, exist_ok=True)
    doc.write_text("\n".join(lines))


def kept_section(doc: Path) -> list[str]:
    """The doc's hand-kept part (between KEEP_BEGIN and KEEP_END) that a rewrite carries over.

    docs/evaluation.md keeps the current corpus's figures there (written by
    experiments/partition_table.py) above the tables this module writes.
    """
    text = doc.read_text() if doc.is_file() else ""
    start, end = text.find(KEEP_BEGIN), text.find(KEEP_END)
    if start < 0 or end < start:
        return []
    return [*text[start : end + len(KEEP_END)].splitlines(), ""]


def budget_section(plans: dict[tuple[str, str], dict[str, Any]]) -> list[str]:
    first = next(iter(plans.values()))
    rows = []
    for (part, variant), p in plans.items():
        rows.append(
            [
                part,
                variant,
                p["loss_weights"],
                f"{p['trained_s'] / 60:.1f}",
                f"{p.get('epochs_done', 0)}/{p['epochs']}",
                str(p["stride"]),
                p["status"],
            ]
        )
    total = sum(p["trained_s"] for p in plans.values()) / 60
    return [
        f"Model config `{first['config']}` for all runs. Each run got an equal share of the",
        f"budget ({first['budget_s'] / 60:.1f} min; `trained` is the wall time of its",
        f"`scotti train` calls, data loading and validation included); {total:.0f} min in all, on",
        "this",
        "2-core machine. The epochs and the stride between training windows were chosen",
        "from the measured training throughput, divided by the runs that share the machine",
        f"({first['measured_windows_per_s']:.0f} windows/s per run), so that the learning-rate",
        "schedule ends within the share (runs marked `stopped` ran out of time before their",
        "last planned epoch: their schedule was cut). **These models are",
        "undertrained**: a few minutes of CPU each, a small fraction of one pass over every",
        "window of the training subjects. Read the figures as what this budget buys, not as",
        "what the architecture can do. docs/accuracy-vs-latency.md trains the same model",
        "(E128-L2-T40) on the same partitions with its own budget per run: compare before",
        "drawing conclusions, in particular about Table 3 (a task the budget has not",
        "reached yet looks the same as a task that sharing hurts).",
        "",
        *table(
            [
                "partition",
                "variant",
                "loss weights (pose,action,progress)",
                "trained (min)",
                "epochs",
                "stride",
                "status",
            ],
            rows,
        ),
    ]


def table1(multi: list[dict[str, Any]], clean: list[dict[str, Any]]) -> list[str]:
    rnd = [r["random_baseline"] for r in multi]
    rows = [
        [
            "Random (uniform progress; uniform action)",
            "-",
            "-",
            fmt([x["action_accuracy"] for x in rnd], 2, 100),
            fmt([x["progress_mse"] for x in rnd], 4),
            fmt([x["app"] for x in rnd], 4),
        ],
        ["SCOTTI, ours (multi-task)"] + [fmt(values(multi, k), d, s) for k, _, d, s, _ in METRICS],
        [
            "SCOTTI, paper (its own data; for reference only)",
            "96.63",
            "-",
            "90.06",
            "0.0223",
            "0.8952",
        ],
    ]
    if clean:
        rows.insert(
            2,
            ["SCOTTI, ours, same held-out subjects without sensor/transport effects"]
            + [fmt(values(clean, k), d, s) for k, _, d, s, _ in METRICS],
        )
    return table(["method", *(c for _, c, _, _, _ in METRICS)], rows)


def table3(v: dict[str, list[dict[str, Any]]]) -> list[str]:
    rows = []
    for variant in ("pose", "action", "progress"):
        cells = [f"{variant} only"]
        for key, _, d, s, _ in METRICS:
            cells.append(fmt(values(v[variant], key), d, s) if TASK_OF[key] == variant else "-")
        rows.append(cells)
    rows.append(["multi-task"] + [fmt(values(v["multi"], k), d, s) for k, _, d, s, _ in METRICS])
    diffs = ["multi - single (paired by partition)"]
    verdicts = []
    for key, column, d, s, lower in METRICS:
        single = values(v[TASK_OF[key]], key)
        both = values(v["multi"], key)
        delta = [b - a for a, b in zip(single, both, strict=True)]
        diffs.append(fmt(delta, d, s))
        mean, sd = mean_sd(delta)
        if not math.isfinite(mean):
            continue
        better = (mean < 0) == lower
        clear = abs(mean) > sd
        word = ("helps" if better else "hurts") if clear else "makes no clear difference"
        verdicts.append(
            f"- {column}: sharing {word} here ({'+' if mean >= 0 else ''}{mean * s:.{d}f}"
            f" ± {sd * s:.{d}f}, multi-task minus {TASK_OF[key]}-only)."
        )
    rows.append(diffs)
    return [
        *table(["model", *(c for _, c, _, _, _ in METRICS)], rows),
        "",
        'Does sharing help? "Clear" means the mean paired difference is larger than its',
        "spread over the three partitions (three partitions are too few for a test).",
        "",
        *verdicts,
    ]


def per_action(multi: list[dict[str, Any]]) -> list[str]:
    names = list(multi[0]["per_action"])
    rows = []
    for name in names:
        per = [r["per_action"][name] for r in multi]
        frames = sum(int(p["frames"]) for p in per)
        cells = [ROW_NAMES.get(name, name), str(frames)]
        cells += [fmt([_num(p[k]) for p in per], d, s) for k, _, d, s, _ in METRICS]
        rows.append(cells)
    return [
        *table(
            ["action", f"frames ({len(multi)} partitions)", *(c for _, c, _, _, _ in METRICS)], rows
        ),
        "",
        "Accuracy per action is the share of that action's frames classified correctly",
        "(recall). Progress is not labelled while standing.",
    ]


def paper_comparison(multi: list[dict[str, Any]]) -> list[str]:
    ours = {k: mean_sd(values(multi, k))[0] for k in PAPER}
    rnd = mean_sd([r["random_baseline"]["app"] for r in multi])[0]

    def side(key: str, lower: bool) -> str:
        better = (ours[key] < PAPER[key]) == lower
        return "better than" if better else "worse than"

    return [
        "Where the comparison holds: the protocol (three subject-wise partitions of 10",
        "training and 5 test subjects, mean over the three), the timing (frames t-T..t-1",
        "predict t), the architecture family and the metric definitions (MPJPE in mm over",
        f"19 keypoints, accuracy over {NUM_ACTIONS} actions, progress MSE, APP as the area "
        "under the",
        f"precision-margin curve, with chance at 2/3: our random baseline gives {rnd:.4f}).",
        "",
        "Where it does not:",
        "- The data. Our subjects are simulated bodies and motions with simulated plantar",
        "  pressure; the paper's are people in a lab. Simulated motions are more regular and",
        "  the labels are exact (no motion-capture noise), which flatters pose and progress;",
        "  the simulated pressure is simpler than a real insole's, which can go either way.",
        "- The keypoints: the paper's 19 are not ours (we use COCO-WholeBody body and feet",
        "  without the face; see ARCHITECTURE.md), so MPJPE is over different joints.",
        "- The training: minutes on two CPU cores with a small model (see the budget above)",
        "  instead of a GPU run of the paper-size model; the models are undertrained.",
        "",
        f"With that said, side by side: MPJPE {ours['mpjpe_mm']:.1f} mm against the paper's "
        f"96.63 mm ({side('mpjpe_mm', True)}), accuracy {100 * ours['action_accuracy']:.2f} % "
        f"against 90.06 % ({side('action_accuracy', False)}), APP {ours['app']:.4f} against "
        f"0.8952 ({side('app', False)}), progress MSE {ours['progress_mse']:.4f} against 0.0223 "
        f"({side('progress_mse', True)}). None of these differences says anything about the",
        "paper's method on real data; they say where our simulator and budget put us.",
    ]


def plot_confusion(
    multi: list[dict[str, Any]], img: Path, name: str = "confusion.png", what: str = ""
) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    actions = multi[0]["confusion"]["actions"]
    n = len(actions)
    total = [
        [sum(r["confusion"]["matrix"][i][j] for r in multi) for j in range(n)] for i in range(n)
    ]
    shares = [[c / max(1, sum(row)) for c in row] for row in total]
    fig, ax = plt.subplots(figsize=(6.4, 5.2), dpi=120)
    image = ax.imshow(shares, vmin=0, vmax=1, cmap="Blues")
    ax.set_xticks(range(n), actions, rotation=45, ha="right", fontsize=7)
    ax.set_yticks(range(n), actions, fontsize=7)
    for i, row in enumerate(shares):
        for j, x in enumerate(row):
            ax.text(
                j,
                i,
                f"{100 * x:.0f}",
                ha="center",
                va="center",
                fontsize=6,
                color="white" if x > 0.5 else "black",
            )
    ax.set(xlabel="predicted", ylabel="true")
    title = f"Action confusion{what}, % of true frames ({len(multi)} partitions summed)"
    ax.set_title(title, fontsize=9)
    fig.colorbar(image, ax=ax, fraction=0.046)
    fig.tight_layout()
    out = img / name
    fig.savefig(out)
    plt.close(fig)
    return out


def plot_curves(
    multi: list[dict[str, Any]],
    img: Path,
    name: str = "precision-margin.png",
    labels: list[str] | None = None,
) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(4.8, 3.8), dpi=120)
    for k, r in enumerate(multi):
        pm = r["precision_margin"]
        part = labels[k] if labels else Path(r["model"]["path"]).name.split("-")[0]
        ax.plot(pm["margins"], pm["precision"], label=f"{part}: APP {pm['app']:.3f}")
    m = [i / 100 for i in range(101)]
    chance = [1 - (1 - x) ** 2 for x in m]  # uniform guess against uniform labels: APP 2/3
    ax.plot(m, chance, "--", color="grey", label="random, uniform labels (APP 2/3)")
    ax.set(xlabel="margin", ylabel="precision", xlim=(0, 1), ylim=(0, 1.02))
    ax.set_title("Progress: precision-margin curve (multi-task)", fontsize=9)
    ax.legend(loc="lower right", fontsize=7)
    fig.tight_layout()
    out = img / name
    fig.savefig(out)
    plt.close(fig)
    return out
