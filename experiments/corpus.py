"""The evaluation corpus and its three subject-wise partitions, in one command.

    nice -n 5 python experiments/corpus.py [--subjects 15] [--minutes-per-action 4]

Every subject is a lab session (``scotti sim corpus``): each action for at
least the given minutes, in sets of varied length and order, standing
between sets, walking and turning round between spots. Writes
data/corpus/realistic/ (every subject with the simulator's
``realistic`` effects preset: sensor gain spread, noise, hysteresis and creep,
crosstalk, clock drift, jitter, packet loss, ...; the preset draws them per
subject), data/corpus/clean/ (the same subjects and motions, no effects: the
same seeds) and
experiments/partitions.json: three partitions of 10 training and 5 test
subjects with disjoint test sets, so that every subject is tested exactly once.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from common import (
    CLEAN,
    COMMANDS,
    PARTITIONS,
    REALISTIC,
    ROOT,
    ExperimentError,
    scotti_command,
    shown,
    write_json,
)

PARTITION_SEED = 2024  # which subjects land in which test set


def partitions(
    subject_ids: list[str], folds: int = 3, seed: int = PARTITION_SEED
) -> list[dict[str, Any]]:
    """``folds`` partitions; partition k tests the k-th slice of a seeded shuffle."""
    import numpy as np

    order = [subject_ids[i] for i in np.random.default_rng(seed).permutation(len(subject_ids))]
    size = len(order) // folds
    out = []
    for k in range(folds):
        test = sorted(order[k * size : (k + 1) * size])
        train = sorted(s for s in subject_ids if s not in test)
        out.append({"name": f"p{k + 1}", "train": train, "test": test})
    return out


def run_streaming(cmd: list[str]) -> None:
    """Run ``cmd`` from the repository root, passing on its lines as they come (one per subject)."""
    line = shown(cmd)
    COMMANDS.append(line)
    print(f"$ {line}", flush=True)
    started = time.monotonic()
    with subprocess.Popen(
        cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    ) as proc:
        assert proc.stdout is not None
        last = "(no output)"
        for out in proc.stdout:
            last = out.rstrip()
            print(f"  {last}", flush=True)
    if proc.returncode != 0:
        msg = f"{line!r} failed with status {proc.returncode}: {last}"
        raise ExperimentError(msg)
    print(f"  ({time.monotonic() - started:.0f} s)", flush=True)


def render_command(out: Path, effects: str, args: argparse.Namespace) -> list[str]:
    """``scotti sim corpus`` into ``out``, run when it has no manifest: a render cut short
    left session files there, which ``--force`` makes again."""
    return scotti_command(
        "sim", "corpus", "-o", out, "--subjects", str(args.subjects), "--seed", str(args.seed),
        "--minutes-per-action", str(args.minutes_per_action), "--effects", effects, "--force",
    )  # fmt: skip


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python experiments/corpus.py", description=__doc__)
    parser.add_argument("--subjects", type=int, default=15)
    parser.add_argument("--minutes-per-action", type=float, default=4.0)
    parser.add_argument("--seed", type=int, default=1)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        for effects, out in (("realistic", REALISTIC), ("none", CLEAN)):
            if (out / "manifest.json").is_file():
                print(f"{out} exists: kept (delete it to render again)")
                continue
            run_streaming(render_command(out, effects, args))
        manifest = json.loads((REALISTIC / "manifest.json").read_text())
        ids = [entry["file"].rsplit(".", 1)[0] for entry in manifest["sessions"]]
        if len(ids) % 3:
            msg = f"{len(ids)} subjects do not split into three equal test sets"
            raise ExperimentError(msg)
        write_json(
            PARTITIONS,
            {
                "corpus": {
                    "realistic": str(REALISTIC.relative_to(REALISTIC.parents[2])),
                    "clean": str(CLEAN.relative_to(CLEAN.parents[2])),
                    "subjects": len(ids),
                    "minutes_per_action": manifest["minutes_per_action"],
                    "seed": manifest["seed"],
                    "effects": sorted({e for s in manifest["sessions"] for e in s["effects"]}),
                    "total_hours": round(manifest["total_duration_s"] / 3600, 2),
                },
                "partition_seed": PARTITION_SEED,
                "partitions": partitions(ids),
            },
        )
        print(f"wrote {PARTITIONS}")
    except ExperimentError as exc:
        print(f"corpus: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
