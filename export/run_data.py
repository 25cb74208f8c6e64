"""A run's data: session files -> train, validation and test windows, and what the
checkpoint records about them (``training_data``)."""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path, PurePath
from typing import Any

from scotti.export.data import SessionArrays, find_sessions, load_session
from scotti.export.validation import Splits, three_way_split
from scotti.export.windows import WindowDataset

log = logging.getLogger("scotti.train")


@dataclass(frozen=True)
class RunData:
    sessions: list[SessionArrays]
    splits: Splits
    train: WindowDataset
    validation: WindowDataset
    test: WindowDataset

    def training_data(self) -> dict[str, Any]:
        """What the checkpoint and the model card record about the data."""
        return {
            "files": [s.path for s in self.sessions],
            "subjects": sorted({s.subject for s in self.sessions}),
            "split": self.splits.describe(),
            "frames": sum(len(s) for s in self.sessions),
            "windows": {
                "train": self.train.count(1),
                "validation": self.validation.count(1),
                "test": self.test.count(1),
            },
            "train_targets": self.train.target_counts(),  # windows per action: no balancing
            "problems": sum_counters(self.sessions),
        }


def same_session_files(recorded: dict[str, Any], now: dict[str, Any]) -> bool:
    """Whether two ``training_data`` records name the same session files, wherever the
    data lies now: the same paths below the files' common folder (a corpus moved or
    copied to another folder, or another machine, keeps its layout) and the same
    number of decoded frames (a file rendered again to another length is not the same)."""
    return _below_common_folder(recorded.get("files", [])) == _below_common_folder(
        now.get("files", [])
    ) and recorded.get("frames") == now.get("frames")


def _below_common_folder(files: Sequence[str]) -> list[str]:
    """Each path relative to the folder that holds them all, sorted."""
    paths = [PurePath(f) for f in files]
    if not paths:
        return []
    try:
        root = PurePath(os.path.commonpath([p.parent for p in paths]))
    except ValueError:  # absolute and relative paths mixed: no common folder, compare as given
        return sorted(p.as_posix() for p in paths)
    return sorted(p.relative_to(root).as_posix() for p in paths)


def load_sessions(paths: Sequence[Path], cache: Path) -> list[SessionArrays]:
    sessions = [load_session(p, cache) for p in find_sessions(paths)]
    for s in sessions:
        bad = {k: v for k, v in s.counters.items() if v}
        log.info(
            "%s: subject %s, %d frames%s", s.path, s.subject, len(s), f", {bad}" if bad else ""
        )
    return sessions


def prepare(
    sessions: list[SessionArrays],
    *,
    window: int,
    allow_invalid: bool,
    test_subjects: Sequence[str] | None,
    test_fraction: float,
    val_subjects: Sequence[str] | None,
    val_fraction: float,
    seed: int,
) -> RunData:
    """Split into train, validation and test, and cut into windows; logs the split."""
    splits = three_way_split(
        sessions,
        test_subjects=test_subjects,
        test_fraction=test_fraction,
        val_subjects=val_subjects,
        val_fraction=val_fraction,
        seed=seed,
    )

    def windows(part: list[SessionArrays]) -> WindowDataset:
        return WindowDataset(part, window, allow_invalid=allow_invalid)

    data = RunData(
        sessions, splits, windows(splits.train), windows(splits.validation), windows(splits.test)
    )
    log.info(
        "%d sessions, subjects train %s / validation %s (%s split) / test %s (%s split), "
        "windows train %d / validation %d / test %d",
        len(sessions),
        ",".join(splits.train_subjects),
        ",".join(splits.validation_subjects) or "-",
        splits.validation_kind,
        ",".join(splits.test_subjects) or "-",
        splits.test_kind,
        data.train.count(1),
        data.validation.count(1),
        data.test.count(1),
    )
    targets = data.train.target_counts()
    total = max(1, sum(targets.values()))
    log.info(
        "training windows per target action: %s",
        ", ".join(f"{name} {n} ({100 * n / total:.1f} %)" for name, n in targets.items()),
    )
    return data


def sum_counters(sessions: list[SessionArrays]) -> dict[str, int]:
    total: dict[str, int] = {}
    for s in sessions:
        for k, v in s.counters.items():
            total[k] = total.get(k, 0) + int(v)
    return total
