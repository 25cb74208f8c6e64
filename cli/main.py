"""``scotti``: one command, one verb per tool.

Each verb lives in the room that owns it and is imported only when asked
for, so ``scotti session info`` never loads onnxruntime and nothing but
``train``/``export`` ever loads torch.
"""

from __future__ import annotations

import argparse
import importlib
import re
import sys
from collections.abc import Sequence
from typing import Protocol, cast

# verb -> (module that implements it, one-line help). The module exposes
# ``add_arguments(parser)`` and ``run(args) -> int``.
VERBS: dict[str, tuple[str, str]] = {
    "session": ("scotti.firmware_protocol.cli", "inspect session files"),
    "board": ("scotti.daemon.tools.board_emulator_cli", "emulate the receiver board on a pty"),
    "sim": ("scotti.sim.cli", "simulate scenes into session files"),
    "import": ("scotti.importers.cli", "import other insoles' and motion-capture recordings"),
    "train": ("scotti.export.train_cli", "train SCOTTI on session files (needs [train])"),
    "train-history": ("scotti.export.history", "draw a training run's history.jsonl into a PNG"),
    "export": ("scotti.export.export_cli", "export a checkpoint to ONNX (needs [train])"),
    "eval": ("scotti.evaluation.cli", "evaluate a model on session files"),
    "calibrate": (
        "scotti.evaluation.calibrate_cli",
        "fit a model's progress calibration on held-out subjects' sessions",
    ),
}
# "verb action" pairs implemented outside the verb's room: ``session export`` runs the
# model and ``session relabel`` the labelling convention, which firmware_protocol (the
# owner of ``session``) must not import.
VERB_ACTIONS: dict[tuple[str, str], tuple[str, str]] = {
    ("session", "export"): (
        "scotti.daemon.outputs.export_cli",
        "replay a session through the model into an MCAP file (Foxglove, ROS 2)",
    ),
    ("session", "relabel"): (
        "scotti.sim.relabel",
        "remake simulated sessions' progress labels by today's labelling convention",
    ),
}


class VerbModule(Protocol):
    def add_arguments(self, parser: argparse.ArgumentParser) -> None: ...

    def run(self, args: argparse.Namespace) -> int: ...


_LITERAL = re.compile(r"``(.+?)``", re.S)


class _Parser(argparse.ArgumentParser):
    """--help from the rooms' docstrings, their reST literals (``x``) shown as 'x'. The
    verbs' own subparsers are made of this class too (argparse's default)."""

    def format_help(self) -> str:
        return _LITERAL.sub(r"'\1'", super().format_help())

    def format_usage(self) -> str:
        return _LITERAL.sub(r"'\1'", super().format_usage())


class UserError(Exception):
    """A mistake of the user's: printed as one line, exit status 2."""


def _load(verb: str) -> VerbModule | None:
    module_name, _ = VERBS[verb]
    try:
        return cast(VerbModule, importlib.import_module(module_name))
    except ModuleNotFoundError as exc:
        if exc.name == module_name:
            return None  # the verb is planned but not built yet
        if exc.name == "torch":
            msg = f"scotti {verb} needs torch: pip install torch==2.13.0 '.[train]'"
            raise UserError(msg) from None
        raise


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = _Parser(prog="scotti", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="verb", metavar="VERB", required=True)
    for verb, (_, help_text) in VERBS.items():
        sub.add_parser(verb, help=help_text, add_help=False)
    if not argv or argv[0] not in VERBS:
        parser.parse_args(argv)  # prints usage or the error, exits
        return 2
    verb = argv[0]
    action = (verb, argv[1]) if len(argv) > 1 else None
    try:
        if action in VERB_ACTIONS:
            module_name, description = VERB_ACTIONS[action]
            module: VerbModule | None = cast(VerbModule, importlib.import_module(module_name))
            verb, argv = " ".join(action), argv[1:]
        else:
            module, description = _load(verb), VERBS[verb][1]
        if module is None:
            print(f"scotti: '{verb}' is not available in this build", file=sys.stderr)
            return 2
        verb_parser = _Parser(prog=f"scotti {verb}", description=description)
        module.add_arguments(verb_parser)
        args = verb_parser.parse_args(argv[1:])
        if verb == "session":
            # Session files label actions by index; the names are the model contract's,
            # which firmware_protocol (the owner of `session`) must not import.
            from scotti.models.contract import ACTIONS

            args.action_names = ACTIONS
        return module.run(args)
    except UserError as exc:
        print(f"scotti {verb}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
