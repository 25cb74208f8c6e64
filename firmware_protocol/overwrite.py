"""The one overwrite rule of the files the ``scotti`` tools write.

An output that exists is refused, in one line naming it, unless ``--force``
(then it is replaced); every tool's ``--help`` says so with ``REFUSED`` and
``FORCE_HELP``. ``scotti sim`` (a scene, ``corpus``, ``render``), ``scotti
import``, ``scotti session export``, ``scotti eval --plots`` and ``scotti
export`` (all the files named after NAME.onnx) follow it; ``scotti train -o``
refuses a directory that holds a run unless ``--resume`` goes on from it or
``--force`` starts over (``export/run_dir.py``). ``scotti calibrate`` edits
the model it is given in place (its progress map replaced): an edit, not an
output, so no ``--force``. The commands that remake the repository's own
documents (``scotti sim realism``) rewrite them in place: git keeps what they
replace. The daemon's recordings follow their own (never overwritten, a new
name per start on request: ``daemon/input/recording.py``), since a service restarts
on its own.

It lives here, in the room every other may import, because all those tools
write session files or files made from them.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Final

REFUSED: Final = "refused if it exists, unless --force"
FORCE_HELP: Final = "replace outputs that exist (without it an existing output is refused)"


class OutputExistsError(FileExistsError):
    """An output that exists and no ``--force``: one line for the user."""


def refuse_existing(paths: Iterable[Path], *, force: bool) -> None:
    """``OutputExistsError`` naming the first of ``paths`` that exists, unless ``force``."""
    if force:
        return
    taken = [p for p in paths if p.exists() or p.is_symlink()]
    if taken:
        more = f" (and {len(taken) - 1} more of its outputs)" if len(taken) > 1 else ""
        msg = f"{taken[0]} exists{more}; --force replaces it"
        raise OutputExistsError(msg)
