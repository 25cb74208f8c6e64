"""Fuzzing as a command: a million hostile inputs through every parser of outside data.

Targets (each input must give a result or the target's own error, nothing else):

- ``decoder``: bytes into ``StreamDecoder`` in random chunks; only packets and
  ``DecodeError`` values come out, the buffer stays bounded, and the packets
  are the same whether the bytes came in one piece or in chunks.
- ``assembler``: adversarial row blocks (wrapping, repeated, jumping seqs,
  odd geometry) into ``FrameAssembler`` and on into the daemon's ``Pairing``;
  frames come out whole-shaped, never the same one twice between restarts.
- ``session``: bytes (random, or a valid session file cut, bit-flipped or
  spliced, or with a msgpack bomb record: deep nesting, lengths claimed past
  the end, many tiny containers) read by ``read_session``; a ``Session`` or a
  ``SessionError``, in bounded memory.
- ``config``: TOML files (the daemon's real keys with hostile values, or a
  valid file mutated) through ``load_settings``; ``Settings`` or one
  ``ConfigError`` line.
- ``csv``, ``npz``, ``h5``, ``vendor``: files of other insoles (tables, and
  vendor exports from the heads of ``--realdata``'s samples), valid ones made
  hostile (cut, garbage, NaN and huge cells, megabyte lines, shapes of 10^9
  declared, zip directories that lie, compression bombs, HDF5 datasets never
  written) through ``scotti import``'s whole path in a worker process under a
  2 GiB address-space limit; a clean import or one ``ImporterError`` line
  that is not out-of-memory (``fuzz_imports``). A crash or a hang of the
  worker is a finding too.

Inputs come from a seeded ``random.Random`` (``fuzz_inputs``): fast enough for
a million in well under an hour on one core, where Hypothesis' own drawing
costs milliseconds per input; the test suite runs the same inputs and checks
through Hypothesis at a small count (the import targets, a whole import each,
run tens of inputs a second, so a long run of them wants ``--max-minutes``;
the suite runs them a few hundred, seeded). Anything else raised is a finding, kept with the
first input that caused it, and the run goes on; ``--keep DIR`` writes each
finding's first file there.

    python -m scotti.daemon.tools.fuzz [--inputs 1000000] [--max-minutes M] [--targets ...]
    python -m scotti.daemon.tools.fuzz --targets csv,npz,h5,vendor --max-minutes 60 --keep f/

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

from scotti.daemon.tools import fuzz_imports, plain_help
from scotti.daemon.tools import fuzz_inputs as inputs

DEFAULT_INPUTS: Final = 1_000_000  # in all, shared equally by the targets
TARGETS: Final = ("decoder", "assembler", "session", "config", *fuzz_imports.IMPORT_TARGETS)


@dataclass
class Outcome:
    target: str
    inputs: int = 0
    seconds: float = 0.0
    findings: dict[str, str] = field(default_factory=dict)  # "Error at file:line" -> input


def target(
    name: str, workdir: Path, realdata: Path = fuzz_imports.REALDATA
) -> tuple[Callable[[random.Random], Any], Callable[[Any], None]]:
    """(make an input, check it) for ``name``."""
    if name in fuzz_imports.IMPORT_TARGETS:
        seeds = fuzz_imports.Seeds(workdir, realdata)
        make_import = fuzz_imports.MAKERS[name]
        return (
            lambda rnd: make_import(rnd, seeds),
            fuzz_imports.IsolatedCheck(workdir / f"worker-{name}"),
        )
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
    if isinstance(exc, fuzz_imports.FindingError):  # described where it happened, in the worker
        return str(exc)
    frames = traceback.extract_tb(exc.__traceback__)
    last = frames[-1] if frames else None
    place = f" at {Path(last.filename).name}:{last.lineno}" if last else ""
    return f"{type(exc).__name__}{place}: {str(exc)[:120]}"


def fuzz(
    name: str,
    count: int,
    seed: int,
    workdir: Path,
    progress_every: int,
    deadline: float,
    keep: Path | None = None,
    realdata: Path = fuzz_imports.REALDATA,
) -> Outcome:
    make, check = target(name, workdir, realdata)
    rnd = random.Random(f"{seed}:{name}")
    outcome = Outcome(name)
    start = time.monotonic()
    every = 256 if name not in fuzz_imports.IMPORT_TARGETS else 8  # imports are slower
    try:
        for i in range(count):
            if i % every == 0 and time.monotonic() > deadline:
                break
            data = make(rnd)
            try:
                check(data)
            except Exception as exc:  # a finding: keep the first input of each kind, go on
                where = _where(exc)
                if where not in outcome.findings and keep is not None:
                    _keep(keep, name, len(outcome.findings), data)
                outcome.findings.setdefault(where, repr(data)[:300])
            outcome.inputs += 1
            if progress_every and (i + 1) % progress_every == 0:
                rate = (i + 1) / (time.monotonic() - start)
                print(f"  {name}: {i + 1} inputs, {rate:.0f}/s", file=sys.stderr, flush=True)
    finally:
        close = getattr(check, "close", None)
        if close is not None:
            close()
    outcome.seconds = time.monotonic() - start
    return outcome


def _keep(folder: Path, name: str, index: int, data: Any) -> None:
    """A finding's input as a file (import cases: the file itself)."""
    folder.mkdir(parents=True, exist_ok=True)
    if isinstance(data, fuzz_imports.ImportCase):
        (folder / f"{name}-{index}{data.suffix}").write_bytes(data.data)
    (folder / f"{name}-{index}.input.txt").write_text(repr(data) + "\n")


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
    p = argparse.ArgumentParser(
        prog="python -m scotti.daemon.tools.fuzz", description=plain_help(__doc__)
    )
    p.add_argument("--inputs", type=int, default=DEFAULT_INPUTS, help="inputs in all")
    p.add_argument("--targets", default=",".join(TARGETS), help="comma-separated")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--progress", type=int, default=50_000, help="inputs between progress lines")
    p.add_argument("--max-minutes", type=float, default=0.0, help="time budget (0: none)")
    p.add_argument("--keep", type=Path, help="write each finding's first input here")
    p.add_argument(
        "--realdata", type=Path, default=fuzz_imports.REALDATA, help="vendor samples' folder"
    )
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
            outcomes.append(
                fuzz(
                    name,
                    per_target,
                    args.seed,
                    Path(tmp),
                    args.progress,
                    deadline,
                    args.keep,
                    args.realdata,
                )
            )
    print_table(outcomes)
    return 1 if any(o.findings for o in outcomes) else 0


if __name__ == "__main__":
    sys.exit(main())
