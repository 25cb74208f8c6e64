"""Fuzzing as a command: a million hostile inputs through every parser of outside data.

Targets (each input must give a result or the target's own error, nothing else):

- ``decoder``: bytes into ``StreamDecoder`` in random chunks; only packets and
  ``DecodeError`` values come out, the buffer stays bounded, and the packets
  are the same whether the bytes came in one piece or in chunks.
- ``assembler``: adversarial row blocks (wrapping, repeated, jumping seqs,
  odd geometry) into ``FrameAssembler`` and on into the daemon's ``Pairing``;
  frames come out whole-shaped, never the same one twice between restarts.
- ``session``: bytes (random, or a valid session file cut, bit-flipped or
  spliced) read by ``read_session``; a ``Session`` or a ``SessionError``.
- ``config``: TOML files (the daemon's real keys with hostile values, or a
  valid file mutated) through ``load_settings``; ``Settings`` or one
  ``ConfigError`` line.

Inputs come from a seeded ``random.Random`` (``fuzz_inputs``): fast enough for
a million in well under an hour on one core, where Hypothesis' own drawing
costs milliseconds per input; the test suite runs the same inputs and checks
through Hypothesis at a small count. Anything else raised is a finding, kept
with the first input that caused it, and the run goes on.

    python -m scotti.daemon.tools.fuzz [--inputs 1000000] [--max-minutes M] [--targets ...]

With ``--max-minutes`` each target gets an equal share of what is left of the
budget (a target done early leaves its time to the next); the table says how
many inputs each one got.
"""

from __future__ import annotations

import argparse
import os
import random
import sys
import tempfile
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

from scotti.daemon.tools import fuzz_inputs as inputs

DEFAULT_INPUTS: Final = 1_000_000  # in all, shared equally by the targets
TARGETS: Final = ("decoder", "assembler", "session", "config")


@dataclass
class Outcome:
    target: str
    inputs: int = 0
    seconds: float = 0.0
    findings: dict[str, str] = field(default_factory=dict)  # "Error at file:line" -> input


def target(
    name: str, workdir: Path
) -> tuple[Callable[[random.Random], Any], Callable[[Any], None]]:
    """(make an input, check it) for ``name``."""
    if name == "decoder":
        return inputs.make_decoder_input, inputs.check_decoder
    if name == "assembler":
        return inputs.make_blocks, inputs.check_assembler
    if name == "session":
        seed = inputs.session_seed(workdir)
        return (
            lambda rnd: inputs.make_session_bytes(rnd, seed),
            lambda data: inputs.check_session(data, workdir),
        )
    return inputs.make_toml, lambda text: inputs.check_config(text, workdir)


def _where(exc: BaseException) -> str:
    frames = traceback.extract_tb(exc.__traceback__)
    last = frames[-1] if frames else None
    place = f" at {Path(last.filename).name}:{last.lineno}" if last else ""
    return f"{type(exc).__name__}{place}: {str(exc)[:120]}"


def fuzz(
    name: str, count: int, seed: int, workdir: Path, progress_every: int, deadline: float
) -> Outcome:
    make, check = target(name, workdir)
    rnd = random.Random(f"{seed}:{name}")
    outcome = Outcome(name)
    start = time.monotonic()
    for i in range(count):
        if i % 256 == 0 and time.monotonic() > deadline:
            break
        data = make(rnd)
        try:
            check(data)
        except Exception as exc:  # a finding: keep the first input of each kind, go on
            outcome.findings.setdefault(_where(exc), repr(data)[:300])
        outcome.inputs += 1
        if progress_every and (i + 1) % progress_every == 0:
            rate = (i + 1) / (time.monotonic() - start)
            print(f"  {name}: {i + 1} inputs, {rate:.0f}/s", file=sys.stderr, flush=True)
    outcome.seconds = time.monotonic() - start
    return outcome


def print_table(outcomes: list[Outcome]) -> None:
    print("| target | inputs | findings | seconds | inputs/s |")
    print("|---|---:|---:|---:|---:|")
    for o in outcomes:
        rate = o.inputs / max(o.seconds, 1e-9)
        print(f"| {o.target} | {o.inputs} | {len(o.findings)} | {o.seconds:.0f} | {rate:.0f} |")
    total = sum(o.inputs for o in outcomes)
    found = sum(len(o.findings) for o in outcomes)
    print(f"| all | {total} | {found} | {sum(o.seconds for o in outcomes):.0f} | |")
    for o in outcomes:
        for what, example in o.findings.items():
            print(f"finding in {o.target}: {what}\n  first input: {example}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m scotti.daemon.tools.fuzz", description=__doc__)
    p.add_argument("--inputs", type=int, default=DEFAULT_INPUTS, help="inputs in all")
    p.add_argument("--targets", default=",".join(TARGETS), help="comma-separated")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--progress", type=int, default=50_000, help="inputs between progress lines")
    p.add_argument("--max-minutes", type=float, default=0.0, help="time budget (0: none)")
    args = p.parse_args(argv)
    names = [n.strip() for n in args.targets.split(",") if n.strip()]
    unknown = [n for n in names if n not in TARGETS]
    if unknown or not names or args.inputs < 1:
        print(f"fuzz: targets must be some of {', '.join(TARGETS)}", file=sys.stderr)
        return 2
    # The config target must see only its file: no SCOTTI_* from this shell.
    for key in [k for k in os.environ if k.startswith("SCOTTI_")]:
        del os.environ[key]
    per_target = max(1, args.inputs // len(names))
    print(f"fuzz: {per_target} inputs per target ({', '.join(names)}), seed {args.seed}")
    outcomes = []
    with tempfile.TemporaryDirectory(prefix="scotti-fuzz-") as tmp:
        end = time.monotonic() + args.max_minutes * 60 if args.max_minutes > 0 else float("inf")
        for n, name in enumerate(names):
            share = (end - time.monotonic()) / (len(names) - n)  # inf without a budget
            deadline = time.monotonic() + share
            outcomes.append(fuzz(name, per_target, args.seed, Path(tmp), args.progress, deadline))
    print_table(outcomes)
    return 1 if any(o.findings for o in outcomes) else 0


if __name__ == "__main__":
    sys.exit(main())
