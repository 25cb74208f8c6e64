"""``scotti session relabel SESSION... --out DIR [--step-cut after_landing]``: a
simulated session's progress labels remade by the labelling convention.

A simulated session carries its ground truth (keypoints, action, progress,
repetition) in label records, written with the labelling convention of the
day it was rendered. When the convention changes (models/progress.py), or to
try a candidate convention (``--step-cut``, ``PeakParams.step_cut``), the
progress and repetition of every label are computed again from the file's
own keypoints and actions, as the simulator labels a new scene, and the file
is written again under ``--out`` with everything else as it was: the same
packets, events and header, in the same order. Rendering a corpus again
would give the same labels and take hours; this reads and writes it (about
5 s for a 50-minute session).

Only simulated sessions: an imported recording's labels come from its
segment file and keypoints, so import it again (``scotti import``), and a
recording made by the daemon has no labels to remake. The output is written
to a temporary name and renamed when whole; an existing output is left alone
unless ``--force``.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scotti.firmware_protocol.errors import SessionError
from scotti.firmware_protocol.session import SessionReader, SessionWriter, find_session_files
from scotti.firmware_protocol.session_records import LabelRecord
from scotti.models.errors import ModelInputError
from scotti.models.progress import STEP_CUTS, PeakParams, label_progress


@dataclass
class Relabelled:
    """What one file's relabelling changed."""

    path: Path
    labels: int = 0
    changed: int = 0  # labels whose progress or repetition moved
    largest_change: float = 0.0  # the largest |progress difference| where both are finite
    # The source ended inside a record (a render cut short): the whole records are
    # copied, the partial one cannot be, and the output says so.
    cut_short: bool = False
    bad_records: int = 0  # whole records of the source that could not be read (not copied)


def relabel_session(source: Path, target: Path, params: PeakParams | None = None) -> Relabelled:
    """Write ``source`` to ``target`` with its progress labels remade (``params``: the
    convention's, by default the one in force); the target is replaced only when the
    new file is whole."""
    with SessionReader(source) as reader:
        if reader.header.source != "simulated":
            msg = (
                f"{source}: a {reader.header.source} session; only simulated sessions are "
                "relabelled (import a recording again with scotti import)"
            )
            raise SessionError(msg)
        old = [r for r in reader if isinstance(r, LabelRecord)]
    report = Relabelled(
        target, len(old), cut_short=reader.truncated, bad_records=reader.bad_records
    )
    if not old:
        msg = f"{source}: no label records to remake"
        raise SessionError(msg)
    keypoints = np.stack([r.keypoints for r in old])
    actions = np.array([r.action for r in old], dtype=np.int64)
    try:
        new = label_progress(keypoints, actions, params or PeakParams())
    except ModelInputError as exc:
        raise SessionError(f"{source}: {exc}") from None
    before = np.array([r.progress for r in old], dtype=np.float32)
    moved = ~np.isclose(before, new.progress, atol=1e-6, equal_nan=True)
    moved |= np.array([r.rep for r in old]) != new.repetition
    report.changed = int(moved.sum())
    both = np.isfinite(before) & np.isfinite(new.progress)
    if both.any():
        report.largest_change = float(np.abs(before[both] - new.progress[both]).max())
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.", suffix=".tmp")
    os.close(fd)
    try:
        _rewrite(source, Path(tmp), new.progress, new.repetition)
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return report


def _rewrite(source: Path, target: Path, progress: np.ndarray, repetition: np.ndarray) -> None:
    label = 0
    with (
        SessionReader(source, source_frames=True, events=True) as reader,
        SessionWriter(target, reader.header, flush_each=False, overwrite=True) as writer,
    ):
        for record in reader.records():
            if isinstance(record, LabelRecord):
                record = LabelRecord(
                    seq=record.seq,
                    t_ns=record.t_ns,
                    keypoints=record.keypoints,
                    action=record.action,
                    progress=float(progress[label]),
                    rep=int(repetition[label]),
                )
                label += 1
            writer.write(record)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "sessions", nargs="+", metavar="SESSION", help="simulated session files or directories"
    )
    parser.add_argument(
        "--out",
        type=Path,
        required=True,
        metavar="DIR",
        help="where the relabelled files go, by their paths under each directory given",
    )
    parser.add_argument(
        "--step-cut",
        choices=STEP_CUTS,
        default=PeakParams().step_cut,
        help="where walking, walking backward and in place start a step (default: %(default)s,"
        " the convention in force)",
    )
    parser.add_argument("--force", action="store_true", help="replace existing output files")


def run(args: argparse.Namespace) -> int:
    try:
        pairs = _targets(args.sessions, args.out)
    except SessionError as exc:
        print(f"scotti session relabel: {exc}", file=sys.stderr)
        return 2
    failed = 0
    for source, target in pairs:
        if source.resolve() == target.resolve():
            print(f"{source}: --out would replace it; give another directory", file=sys.stderr)
            failed += 1
            continue
        if target.exists() and not args.force:
            print(f"{target} exists; left alone (--force replaces it)", file=sys.stderr)
            failed += 1
            continue
        try:
            done = relabel_session(source, target, PeakParams(step_cut=args.step_cut))
        except SessionError as exc:
            print(f"scotti session relabel: {exc}", file=sys.stderr)
            failed += 1
            continue
        lost = ""
        if done.cut_short:
            lost += "; the source is cut short: its partial last record is not in the copy"
        if done.bad_records:
            lost += f"; {done.bad_records} unreadable records of the source are not in the copy"
        print(
            f"{target}: {done.changed} of {done.labels} labels changed"
            f" (largest progress change {done.largest_change:.2f}){lost}"
        )
    return 1 if failed else 0


def _targets(sessions: list[str], out: Path) -> list[tuple[Path, Path]]:
    pairs: list[tuple[Path, Path]] = []
    for given in map(Path, sessions):
        for source in find_session_files([given]):
            relative = source.relative_to(given) if given.is_dir() else Path(source.name)
            pairs.append((source, out / relative))
    return pairs
