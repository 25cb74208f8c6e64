"""What the experiment drivers share: running ``scotti`` verbs, partitions, budgets, tables.

The drivers are plain scripts, not part of the installed daemon. They call
the ``scotti`` CLI verbs in subprocesses (train, export, eval), so each
figure in the docs comes from the same commands a user would type, and
every command line they run is logged to be quoted in the docs.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
import shlex
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "data" / "corpus"
REALISTIC = DATA / "realistic"
CLEAN = DATA / "clean"
PARTITIONS = ROOT / "experiments" / "partitions.json"
RUNS = ROOT / "runs"
DOCS = ROOT / "docs"
IMG = DOCS / "img"

# Command lines run so far in this process, to be quoted in the docs.
COMMANDS: list[str] = []


# What a rendered session depends on besides its scene: the simulator, the labelling
# convention (models/) and the session format. A render kept under data/ by an
# experiment is made again when these change (``render_is_current``): kept renders
# keyed on the scene alone went on carrying the labels of the day they were made.
RENDER_CODE = ("sim/**/*.py", "models/*.py", "firmware_protocol/*.py")


class ExperimentError(Exception):
    """A step failed: one line for the user."""


def source_digest(patterns: Sequence[str], root: Path | None = None) -> str:
    """A hash of the files matching ``patterns`` under ``root`` (the repository):
    their names and bytes. Caches key on it so that a code change remakes them."""
    root = ROOT if root is None else root
    h = hashlib.sha256()
    for pattern in patterns:
        for path in sorted(root.glob(pattern)):
            h.update(str(path.relative_to(root)).encode())
            h.update(path.read_bytes())
    return h.hexdigest()[:16]


def simulator_digest() -> str:
    """A hash of every source file that makes a rendered session (``RENDER_CODE``)."""
    return source_digest(RENDER_CODE)


def render_is_current(rendered: Path) -> bool:
    """Whether ``rendered`` exists and was made by the simulator as it is now (its
    stamp, ``NAME.simulator``, written by ``stamp_render``)."""
    stamp = rendered.with_name(rendered.name + ".simulator")
    return rendered.exists() and stamp.is_file() and stamp.read_text() == simulator_digest()


def stamp_render(rendered: Path) -> None:
    """Record that ``rendered`` was made by the simulator as it is now."""
    rendered.with_name(rendered.name + ".simulator").write_text(simulator_digest())


def scotti_command(*args: str | Path) -> list[str]:
    """The ``scotti`` CLI of this interpreter's environment."""
    return [sys.executable, "-m", "scotti.cli.main", *map(str, args)]


def shown(cmd: Sequence[str]) -> str:
    """A command line as a user would type it (``scotti ...``, paths relative to the repo)."""
    words = list(cmd)
    if words[:3] == [sys.executable, "-m", "scotti.cli.main"]:
        words = ["scotti", *words[3:]]
    elif words[:1] == [sys.executable]:
        words = ["python", *words[1:]]
    root = str(ROOT) + os.sep
    return shlex.join(w.replace(root, "") for w in words)


def run(cmd: Sequence[str], log: Path | None = None, *, quote: bool = True) -> str:
    """Run ``cmd`` from the repository root; its stdout is returned, both streams logged."""
    line = shown(cmd)
    if quote:
        COMMANDS.append(line)
    print(f"$ {line}", flush=True)
    started = time.monotonic()
    proc = subprocess.run(list(cmd), cwd=ROOT, capture_output=True, text=True, check=False)
    if log is not None:
        log.parent.mkdir(parents=True, exist_ok=True)
        with log.open("a") as f:
            f.write(f"$ {line}\n{proc.stdout}{proc.stderr}\n")
    if proc.returncode != 0:
        tail = (proc.stderr.strip() or proc.stdout.strip()).splitlines()[-1:] or ["(no output)"]
        msg = f"{line!r} failed with status {proc.returncode}: {tail[0]}"
        raise ExperimentError(msg)
    print(f"  ({time.monotonic() - started:.0f} s)", flush=True)
    return proc.stdout


def run_parallel(
    cmds: Sequence[Sequence[str]], log: Path, then: Callable[[int], object] | None = None
) -> list[str]:
    """Run commands side by side (one per core); their stdouts in order.

    ``then(i)`` runs as soon as command ``i`` has ended well, while the others go on:
    a run whose training ended is scored on the core it freed, not after the slowest
    run. A failed command raises once every command (and its ``then``) has ended.
    """
    procs = []
    for cmd in cmds:
        COMMANDS.append(shown(cmd))
        print(f"$ {shown(cmd)} &", flush=True)
        procs.append(
            subprocess.Popen(
                list(cmd), cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
            )
        )
    log_lock = threading.Lock()

    def wait(i: int) -> str:
        out, err = procs[i].communicate()
        with log_lock:
            log.parent.mkdir(parents=True, exist_ok=True)
            with log.open("a") as f:
                f.write(f"$ {shown(cmds[i])}\n{out}{err}\n")
        if procs[i].returncode != 0:
            tail = (err.strip() or out.strip()).splitlines()[-1:] or ["(no output)"]
            msg = f"{shown(cmds[i])!r} failed with status {procs[i].returncode}: {tail[0]}"
            raise ExperimentError(msg)
        if then is not None:
            then(i)
        return out

    with ThreadPoolExecutor(max_workers=max(1, len(procs))) as pool:  # waits for all
        waits = [pool.submit(wait, i) for i in range(len(procs))]
    return [w.result() for w in waits]  # the first failure, in command order, raises


# --- partitions -----------------------------------------------------------------


@dataclass(frozen=True)
class Partition:
    name: str
    train: tuple[str, ...]  # subject ids (session file stems)
    test: tuple[str, ...]
    corpus: Path = REALISTIC  # the directory holding the subjects' session files

    def test_files(self) -> list[Path]:
        return [session_file(self.corpus, s) for s in self.test]


def session_file(corpus: Path, subject: str) -> Path:
    path = corpus / f"{subject}.ses"
    if not path.is_file():
        msg = f"{path} is missing: run python experiments/corpus.py first"
        raise ExperimentError(msg)
    return path


def load_partitions(path: Path = PARTITIONS) -> list[Partition]:
    try:
        raw = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        msg = f"cannot read {path}: {exc}; run python experiments/corpus.py first"
        raise ExperimentError(msg) from None
    corpus = ROOT / raw["corpus"]["realistic"]
    return [
        Partition(p["name"], tuple(p["train"]), tuple(p["test"]), corpus) for p in raw["partitions"]
    ]


# --- training within a budget ---------------------------------------------------

THROUGHPUT = re.compile(r"chunked ([0-9.]+) windows/s")
WINDOWS = re.compile(r"windows train (\d+)")


def epochs_for(budget_min: float, windows_per_s: float, train_windows: int, stride: int) -> int:
    """Whole epochs that fit the budget (at least 1), so the LR schedule runs to its end."""
    per_epoch = max(1, train_windows // stride)
    return max(1, math.floor(0.9 * budget_min * 60.0 * windows_per_s / per_epoch))


def last_history(run_dir: Path) -> dict[str, Any]:
    """The final epoch record of a run (history.jsonl), empty if none."""
    path = run_dir / "history.jsonl"
    if not path.is_file():
        return {}
    lines = [ln for ln in path.read_text().splitlines() if ln.strip()]
    return dict(json.loads(lines[-1])) if lines else {}


# --- figures --------------------------------------------------------------------


def mean_sd(values: Sequence[float]) -> tuple[float, float]:
    """Mean and sample standard deviation (0 for one value); NaNs left out."""
    v = [x for x in values if x is not None and math.isfinite(x)]
    if not v:
        return math.nan, math.nan
    mean = sum(v) / len(v)
    if len(v) == 1:
        return mean, 0.0
    return mean, math.sqrt(sum((x - mean) ** 2 for x in v) / (len(v) - 1))


def fmt(values: Sequence[float], digits: int, scale: float = 1.0) -> str:
    """``mean ± sd`` over the partitions, or a dash."""
    kept = [x * scale for x in values if x is not None and math.isfinite(x)]
    mean, sd = mean_sd(kept)
    if not math.isfinite(mean):
        return "-"
    if len(kept) == 1:
        return f"{mean:.{digits}f}"  # one value has no spread
    return f"{mean:.{digits}f} ± {sd:.{digits}f}"


# --- writing docs ---------------------------------------------------------------
# Every driver that writes into docs/ does it through these: a markdown table, and
# the text between a doc's ``<!-- NAME:begin -->`` and ``<!-- NAME:end -->`` lines.


def table(header: Sequence[str], rows: Sequence[Sequence[str]], align: str = "") -> list[str]:
    """A markdown table's lines; ``align`` has an ``r`` for each right-aligned column."""
    rule = "".join("---:|" if a == "r" else "---|" for a in align.ljust(len(header), "l"))
    lines = ["| " + " | ".join(header) + " |", "|" + rule]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return lines


def write_between_markers(doc: Path, text: str, begin: str, end: str) -> None:
    """Replace what stands between DOC's ``begin`` and ``end`` lines with ``text``."""
    content = doc.read_text()
    start, stop = content.find(begin), content.find(end)
    if start < 0 or stop < start:
        raise ExperimentError(f"{doc}: no {begin} ... {end} section to write into")
    doc.write_text(content[: start + len(begin)] + "\n" + text + content[stop:])


def write_card_section(card: Path, text: str, section: str) -> None:
    """Put ``text`` between the card's ``<!-- SECTION:begin/end -->`` lines, adding them at
    its end when it has none: a card written by scripts/ship_default.py has none, since
    what was measured of the model after it shipped (the coverage grid, the real files)
    belongs to that model alone, and a new default's card starts without it."""
    begin, end = f"<!-- {section}:begin -->", f"<!-- {section}:end -->"
    content = card.read_text()
    if content.find(begin) < 0 or content.find(end) < content.find(begin):
        card.write_text(content.rstrip("\n") + f"\n\n{begin}\n{end}\n")
    write_between_markers(card, text, begin, end)


def write_section(doc: Path, text: str, section: str) -> None:
    """Replace what stands between DOC's ``<!-- SECTION:begin/end -->`` lines."""
    write_between_markers(doc, text, f"<!-- {section}:begin -->", f"<!-- {section}:end -->")


def read_json(path: Path) -> dict[str, Any]:
    return dict(json.loads(path.read_text()))


def write_json(path: Path, value: Any) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(value, indent=2) + "\n")


def pairs(items: Sequence[str], what: str) -> dict[str, Path]:
    """``NAME=PATH`` arguments as a mapping; a malformed one is an ExperimentError."""
    out = {}
    for item in items:
        name, sep, path = item.partition("=")
        if not sep or not name or not path:
            raise ExperimentError(f"{what} {item!r}: expected NAME=PATH")
        out[name] = Path(path)
    return out


def from_root(path: str | Path) -> str:
    """A path as the docs quote it: relative to the repository root when inside it."""
    p = Path(path)
    return str(p.relative_to(ROOT)) if p.is_absolute() and p.is_relative_to(ROOT) else str(p)


def utc_now() -> str:
    return time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())


def scoring(every: int) -> str:
    """How the held-out prediction times were scored, in words."""
    if every == 1:
        return "every prediction time scored through the streaming step graph"
    return (
        f"every {every}th prediction time scored, through the window graph in batches (the "
        "step graph's weights: the export proves the two graphs agree)"
    )
