"""The shipped model's recipe on each subject-wise partition, to its plateau, then scored.

    nice -n 5 python experiments/partition_runs.py p2 p3 --max-minutes 112   # side by side
    python experiments/partition_runs.py p2 p3 --max-minutes 60             # goes on from there
    python experiments/partition_runs.py p1 --variant progress              # Table 3's variants
    python experiments/partition_runs.py p3 --arch E128-L2-T20              # the sweep's configs
    python experiments/partition_runs.py p1 --form streaming                # streaming-native

Per partition of experiments/partitions.json, in runs/GROUP-PARTITION[-VARIANT]:

1. ``scotti train`` on the partition's training subjects of the current corpus
   plus the 18 people of ``extra`` (none of them in any partition's test set),
   validated on the last two training subjects and subject-031/032 (for p1
   the shipped model's validation subjects), with the shipped model's loss
   weights, until the plateau rule or ``--epochs`` ends it. A run that
   ``--max-minutes`` stopped resumes from last.pt on the next call (several
   partitions train side by side, one process and thread each).
2. As soon as its training has ended (the other runs go on, and this run is
   scored on the core it freed): ``scotti export --calibrate`` (the unfamiliar
   score), ``scotti calibrate`` on the validation subjects (the progress map,
   fitted as the shipped model's was) and ``scotti eval --json`` on the
   partition's held-out subjects into eval/test.json.

``--arch NAME`` trains one of the configurations of experiments/configs.py
instead of ``small`` (with that width's learning rate unless ``--lr`` says
otherwise), into runs/GROUP-PARTITION-NAME; a model whose window is not the
contract's 40 is calibrated and scored through experiments/any_window.py.
``--form streaming`` trains the streaming-native form (``scotti train --arch
streaming``: relative positions, causal attention, a key/value cache;
docs/streaming-native.md) with the same recipe, into runs/GROUP-PARTITION[...]-streaming;
it is exported, calibrated and scored by the same commands (``scotti export``,
``calibrate`` and ``eval`` take either form). It combines with ``--arch NAME``, which
picks the size, not the form.
``--max-crosstalk X`` trains with crosstalk added per chunk and foot
(export/augment.py), into runs/GROUP-PARTITION[-VARIANT]-xtX.
``--precision bf16`` trains under bf16 autocast (validation and the exported
graphs stay fp32), into runs/GROUP-PARTITION[...]-bf16.
``--more FOLDER...`` adds every person of those folders of the corpus to the
training subjects (``scotti sim corpus --first-subject 33``: people no partition
tests on), into runs/GROUP-PARTITION[...]-FOLDER.
``--init MODEL`` starts the run from a checkpoint's or an exported graph's
weights instead of from scratch (``scotti train --init``: training the shipped
model on, with a fresh schedule); a graph is then scored beside the new model in
the same replay, so the two are compared on the same held-out frames.
``--beside PARTITION=MODEL`` scores a further graph in that partition's replay
(say, the shipped default beside a new recipe's p1 model); name only
partitions whose held-out subjects that graph never trained or validated on.

Then ``experiments/partition_table.py`` puts the reports side by side. The
test subjects are never given to ``scotti train``: not for training, not for
validation, not for the calibrations.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

from common import (
    ROOT,
    RUNS,
    ExperimentError,
    last_history,
    load_partitions,
    pairs,
    run,
    run_parallel,
    scotti_command,
)
from configs import CONFIGS, CONTRACT_WINDOW, learning_rate, window_of

HERE = Path(__file__).resolve().parent
CORPUS = ROOT / "data" / "corpus7"
EXTRA_VALIDATION = ("subject-031", "subject-032")
# The shipped model's loss weights (pose, action, progress) and Table 3's single tasks.
LOSS_WEIGHTS = {"multi": "0.01,1,3", "pose": "0.01,0,0", "action": "0,1,0", "progress": "0,0,1"}
FORMS = ("paper", "streaming")  # scotti train --arch (export/model.py's ARCHES)


@dataclass(frozen=True)
class PartitionRun:
    partition: str
    train: tuple[str, ...]  # the partition's training subjects (data/corpus7/realistic)
    test: tuple[str, ...]
    run_dir: Path
    variant: str = "multi"
    window: int = CONTRACT_WINDOW
    init: Path | None = None  # weights to start from (scotti train --init), else from scratch
    more: tuple[str, ...] = ()  # further corpus folders whose people all train (--more)
    beside: Path | None = None  # a further graph scored in the same replay (--beside)
    form: str = "paper"  # scotti train --arch: the paper's encoder or the streaming-native one

    @property
    def validation(self) -> tuple[str, ...]:
        return (*self.train[-2:], *EXTRA_VALIDATION)

    def files(self, corpus: Path, subjects: tuple[str, ...] = ()) -> list[Path]:
        """Session files: these subjects, or all the run may see (training and validation)."""
        if subjects:
            return [_session(corpus, s) for s in subjects]
        extra = sorted((corpus / "extra").glob("subject-*.ses"))
        extra += [f for part in self.more for f in _people(corpus, part)]
        return [*(_session(corpus, s) for s in self.train), *extra]

    def train_command(self, corpus: Path, opts: argparse.Namespace) -> list[str]:
        resume = ["--resume"] if (self.run_dir / "last.pt").is_file() else []
        # With --init the size is the starting model's (scotti train refuses --config beside
        # it); it is passed on resume too, so the checkpoints keep saying where they started.
        start = ["--init", str(self.init)] if self.init else ["--config", opts.config]
        return scotti_command(
            "train", *self.files(corpus), "-o", self.run_dir, *start,
            "--val-subjects", *self.validation, "--test-fraction", "0",
            "--epochs", str(opts.epochs), "--patience", "3", "--stride", str(opts.stride),
            "--val-stride", "8", "--lr", str(opts.lr),
            "--loss-weights", LOSS_WEIGHTS[self.variant], "--threads", str(opts.threads),
            "--max-minutes", str(opts.max_minutes), "--cache", str(opts.cache),
            "--max-crosstalk", str(opts.max_crosstalk), "--ema", str(opts.ema),
            "--precision", opts.precision, *self.form_args(), *resume,
        )  # fmt: skip

    def form_args(self) -> list[str]:
        """``scotti train --arch`` for the streaming-native form; nothing for the paper form,
        so its commands stay as they were."""
        return [] if self.form == "paper" else ["--arch", self.form]

    def eval_models(self, model: Path, before: Path) -> list[str | Path]:
        """``scotti eval``'s models, the calibrated graph first (partition_table takes it)."""
        models: list[str | Path] = ["--model", model, "--model", before]
        if self.init is not None and self.init.suffix == ".onnx":
            models += ["--model", self.init]  # the graph it started from, on the same frames
        if self.beside is not None:
            models += ["--model", self.beside]
        return models

    def finished(self, epochs: int) -> bool:
        """Training has ended: the plateau rule stopped it or its epochs are done."""
        last = last_history(self.run_dir)
        return bool(last) and (last.get("status") == "plateau" or int(last["epoch"]) >= epochs)

    def scored(self) -> bool:
        return (self.run_dir / "eval" / "test.json").is_file()


def _people(corpus: Path, part: str) -> list[Path]:
    files = sorted((corpus / part).glob("subject-*.ses"))
    if not files:
        raise ExperimentError(f"no session files in {corpus / part}: see export/TRAINING.md")
    return files


def _session(corpus: Path, subject: str) -> Path:
    for part in ("realistic", "extra"):
        path = corpus / part / f"{subject}.ses"
        if path.is_file():
            return path
    raise ExperimentError(f"no session file for {subject} under {corpus}: see export/TRAINING.md")


def verb(window: int, *args: str | Path) -> list[str]:
    """A ``scotti`` verb for a model of this window (see experiments/any_window.py)."""
    if window == CONTRACT_WINDOW:
        return scotti_command(*args)
    return [sys.executable, str(HERE / "any_window.py"), str(window), *map(str, args)]


def score(job: PartitionRun, corpus: Path, cache: Path) -> Path:
    """Export with both calibrations, then the held-out evaluation; the report's path.

    The report holds two models scored in one replay: the calibrated graphs first
    (what partition_table.py takes), then the same weights with the export's progress
    map instead of the one ``scotti calibrate`` fits, to show what that refit buys.
    """
    model = job.run_dir / "models" / "scotti-ship.onnx"
    log = job.run_dir / "score.log"
    run(verb(job.window, *export_command(job, corpus, cache)), log)
    before = job.run_dir / "models" / "export-fit"
    before.mkdir(exist_ok=True)
    for graph in (model, model.with_name("scotti-ship.window.onnx")):
        shutil.copy2(graph, before / graph.name)
    run(verb(job.window, "calibrate", model, *job.files(corpus, job.validation)), log)
    report = job.run_dir / "eval" / "test.json"
    models = job.eval_models(model, before / model.name)
    out = run(verb(job.window, "eval", *job.files(corpus, job.test), *models, "--json"), log)
    report.parent.mkdir(parents=True, exist_ok=True)
    report.write_text(out)
    return report


def export_command(job: PartitionRun, corpus: Path, cache: Path | str) -> list[str | Path]:
    """``scotti export`` of the run's best.pt, calibrated, into RUN/models/scotti-ship.onnx.

    ``--force``: scoring again (the run trained on, or a scoring was cut short) replaces
    the graphs an earlier scoring exported; ``scotti calibrate`` then edits the new ones.
    """
    model = job.run_dir / "models" / "scotti-ship.onnx"
    export = ["export", job.run_dir / "best.pt", "-o", model, "--calibrate"]
    return [*export, *job.files(corpus), "--cache-dir", cache, "--force"]


def plan(args: argparse.Namespace) -> list[PartitionRun]:
    """The runs asked for; resolves ``--arch`` into ``--config``, ``--lr`` and the window."""
    known = {p.name: p for p in load_partitions()}
    unknown = sorted(set(args.partitions) - set(known))
    if unknown:
        raise ExperimentError(f"unknown partitions {', '.join(unknown)}: {', '.join(known)}")
    suffix = "" if args.variant == "multi" else f"-{args.variant}"
    window = CONTRACT_WINDOW
    if args.arch:
        args.config = json.dumps(CONFIGS[args.arch])
        args.lr = args.lr or learning_rate(args.arch)
        window = window_of(args.arch)
        suffix += f"-{args.arch}"
    args.lr = args.lr or 1e-3
    if args.max_crosstalk > 0:
        suffix += f"-xt{args.max_crosstalk:g}"
    for part in args.more:
        suffix += f"-{part}"
    if args.precision != "fp32":
        suffix += f"-{args.precision}"
    if args.form != "paper":
        suffix += f"-{args.form}"
    beside = _beside(args.beside, args.partitions)
    return [
        PartitionRun(
            n,
            known[n].train,
            known[n].test,
            RUNS / f"{args.group}-{n}{suffix}",
            args.variant,
            window,
            args.init,
            tuple(args.more),
            beside.get(n),
            args.form,
        )
        for n in args.partitions
    ]


def _beside(specs: list[str], partitions: list[str]) -> dict[str, Path]:
    """``--beside PARTITION=MODEL`` options; refuses what cannot be scored."""
    # Made absolute here: the scotti commands run in the repository root, not the caller's folder.
    graphs = {name: path.absolute() for name, path in pairs(specs, "--beside").items()}
    for name, path in graphs.items():
        if name not in partitions:
            raise ExperimentError(f"--beside {name}: not among this call's partitions")
        if not path.is_file():
            raise ExperimentError(f"--beside {name}={path}: no such model file")
    return graphs


def absolute_path(text: str) -> Path:
    """A path option made absolute: the scotti commands run in the repository root."""
    return Path(text).absolute()


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python experiments/partition_runs.py",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("partitions", nargs="+", help="p1, p2, p3")
    parser.add_argument("--variant", choices=sorted(LOSS_WEIGHTS), default="multi")
    parser.add_argument("--group", default="v9", help="runs/GROUP-PARTITION[-VARIANT]")
    parser.add_argument(
        "--corpus", type=absolute_path, default=CORPUS, help="with realistic/ and extra/"
    )
    parser.add_argument(
        "--cache", type=absolute_path, default=ROOT / "data" / "cache7", help="scotti train --cache"
    )
    parser.add_argument("--config", default="small", help="scotti train --config")
    parser.add_argument("--arch", choices=sorted(CONFIGS), help="instead of --config")
    parser.add_argument(
        "--form",
        choices=FORMS,
        default="paper",
        help="scotti train --arch: paper (the shipped form) or streaming (the streaming-native "
        "form, -streaming runs); the size comes from --config or --arch either way",
    )
    parser.add_argument("--epochs", type=int, default=8, help="the cosine schedule's length")
    parser.add_argument("--stride", type=int, default=16)
    parser.add_argument("--lr", type=float, help="default 1e-3, or the --arch's width's")
    parser.add_argument("--max-minutes", type=float, default=112, help="per run, this call")
    parser.add_argument(
        "--max-crosstalk", type=float, default=0.0, help="scotti train's augmentation (-xtX runs)"
    )
    parser.add_argument(
        "--ema", type=float, default=0.0, help="scotti train --ema (name the --group after it)"
    )
    parser.add_argument(
        "--more",
        nargs="+",
        default=[],
        metavar="FOLDER",
        help="further folders of --corpus whose people all train beside extra/ (-FOLDER runs)",
    )
    parser.add_argument("--threads", type=int, default=1, help="scotti train --threads per run")
    parser.add_argument(
        "--precision",
        choices=("fp32", "bf16"),
        default="fp32",
        help="scotti train --precision: bf16 autocasts the training step (-bf16 runs)",
    )
    parser.add_argument(
        "--init",
        type=absolute_path,
        help="start from this checkpoint or exported graph (scotti train --init), not from scratch",
    )
    parser.add_argument(
        "--beside",
        action="append",
        default=[],
        metavar="PARTITION=MODEL",
        help="also score this graph in that partition's held-out replay (once per partition)",
    )
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        jobs = plan(args)
        training = [j for j in jobs if not j.finished(args.epochs)]
        for job in training:
            job.run_dir.mkdir(parents=True, exist_ok=True)
        commands = [j.train_command(args.corpus, args) for j in training]

        def score_if_ended(i: int) -> None:
            """Score a run whose training has ended, while the others still train."""
            job = training[i]
            if job.finished(args.epochs) and not job.scored():
                score(job, args.corpus, args.cache)

        if commands:
            run_parallel(commands, RUNS / f"{args.group}-train.log", then=score_if_ended)
        for job in jobs:
            if not job.finished(args.epochs):
                print(f"{job.run_dir}: training goes on at the next call (--max-minutes ran out)")
        done = [j for j in jobs if j.finished(args.epochs)]
        todo = [j for j in done if not j.scored()]  # runs that had ended before this call
        with ThreadPoolExecutor(max_workers=2) as pool:  # one core each
            list(pool.map(lambda j: score(j, args.corpus, args.cache), todo))
        for job in done:
            report = (job.run_dir / "eval" / "test.json").relative_to(ROOT)
            run_dir = job.run_dir.relative_to(ROOT)
            print(f"{job.partition}={report} --run {job.partition}={run_dir}")
    except ExperimentError as exc:
        print(f"partition_runs: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
