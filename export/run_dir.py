"""What a ``scotti train -o RUN_DIR`` may find there: the overwrite rule of a run.

A run directory that holds a run (any of ``RUN_FILES``) is refused, unless
``--resume`` (go on from its last.pt) or ``--force`` (start over: that run's
files are deleted before the new run writes its first). Other files in it
(exported models, logs, an experiment's plan.json) are no run and are left
alone. This is ``firmware_protocol/overwrite.py``'s rule for a directory whose
files belong together: a new run beside an old one's best.pt or test.json
would leave figures of the old run under the new run's name.
"""

from __future__ import annotations

from pathlib import Path
from typing import Final

from scotti.export.errors import ExportError

# What a run writes (export/train.py, export/test_report.py); last.pt comes first.
RUN_FILES: Final = ("last.pt", "best.pt", "history.jsonl", "test.json")


class RunExistsError(ExportError):
    """A run directory that holds a run, and neither --resume nor --force: one line."""


def run_files(run_dir: Path) -> list[str]:
    """The names of ``RUN_FILES`` that exist in ``run_dir``."""
    return [name for name in RUN_FILES if (run_dir / name).exists()]


def check_run_dir(run_dir: Path, *, resume: bool, force: bool) -> None:
    """``RunExistsError`` unless ``run_dir`` holds no run, or may go on or be replaced."""
    held = run_files(run_dir)
    if not held or force or (resume and "last.pt" in held):
        return
    names = ", ".join(held)
    if resume:
        msg = f"{run_dir} holds a run ({names}) but no last.pt to resume; --force starts over"
    else:
        msg = f"{run_dir} holds a run ({names}); --resume goes on from it, --force starts over"
    raise RunExistsError(msg)


def clear_run(run_dir: Path) -> list[str]:
    """Delete the run's files in ``run_dir`` (``--force``); the names deleted."""
    held = run_files(run_dir)
    for name in held:
        (run_dir / name).unlink()
    return held
