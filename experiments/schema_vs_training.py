"""How much of the range the scene schema accepts a model's training data covers.

    python experiments/schema_vs_training.py                       # the shipped model
    python experiments/schema_vs_training.py --model M --tempo-range 0.65 1.3 \
        --tempo-extra-range 0.3 3

Issue 37 asks training to draw every parameter a scene may set over the whole
range the schema accepts. For each numeric field of a person, the insole and the
effects (experiments/coverage_grid.py reads them from the schema), this puts the
schema's range beside the values the model's training sessions hold: the files
its card names (``training_data.files``), each file's scene as written in its
header, every movement trait and the foot's shape resolved as the simulator
resolves them (drawn from the person's style seed unless the scene gives them).
Training's augmentations that act like another insole (``--sensor-transfer``)
are not in these rows. ``script.tempo`` is not in a
lab session's scene: training stretches it (``--tempo-stretch``,
``--tempo-extra``), and the ranges it was trained with are given here.

"covered" is the share of the schema's span between the smallest and the
largest training value (in the field's units; a field whose training values
are all one value covers 0 %). An effect a session does not carry counts as
its default-free absence: its parameters then have no value in that session. A
measurement, never a test; it reads only the files' headers (seconds).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from coverage_grid import SchemaField, schema_fields
from scotti.firmware_protocol.errors import SessionError
from scotti.firmware_protocol.session import SessionReader
from scotti.models.kv_streaming import open_step_model
from scotti.sim.foot import draw_shape
from scotti.sim.scene import SubjectModel
from scotti.sim.traits import TRAIT_NAMES

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_MODEL = ROOT / "models" / "scotti-default.onnx"
GROUPS = ("subject.", "insole.", "effects.")


@dataclass(frozen=True)
class Row:
    path: str
    low: float
    high: float
    seen: tuple[float, ...]  # the training sessions' values (empty: none holds it)

    @property
    def covered(self) -> float:
        """Share of the schema's span between the least and the most a session holds."""
        if not self.seen or self.high <= self.low:
            return 0.0
        return (max(self.seen) - min(self.seen)) / (self.high - self.low)


def session_values(scene: dict[str, Any]) -> dict[str, float]:
    """Every numeric field of a session's scene, traits resolved as the simulator does."""
    out: dict[str, float] = {}
    subject = SubjectModel.model_validate(scene["subject"])
    person = subject.subject()
    out["subject.height_m"] = person.height_m
    out["subject.mass_kg"] = person.mass_kg
    out["subject.foot_length_m"] = person.foot_length
    shape = draw_shape(
        person.foot_length, person.style_seed, subject.arch, subject.ball_width_ratio
    )
    out["subject.ball_width_ratio"] = shape.ball_width_ratio
    for name in TRAIT_NAMES:
        value = getattr(person.traits, name)
        if isinstance(value, int | float):
            out[f"subject.{name}"] = float(value)
    for name, value in (scene.get("insole") or {}).items():
        if isinstance(value, int | float):
            out[f"insole.{name}"] = float(value)
    for effect in scene.get("effects") or []:
        for name, value in effect.items():
            if name != "name" and isinstance(value, int | float) and not isinstance(value, bool):
                out[f"effects.{effect['name']}.{name}"] = float(value)
    return out


def rows(files: list[Path], fields: list[SchemaField]) -> tuple[list[Row], int]:
    """A row per numeric field of the three groups; how many files had a scene."""
    seen: dict[str, list[float]] = {}
    read = 0
    for path in files:
        try:
            with SessionReader(path) as reader:
                scene = reader.header.scene
        except SessionError as exc:
            print(f"schema_vs_training: {exc}", file=sys.stderr)
            continue
        if not scene:
            continue
        read += 1
        for key, value in session_values(scene).items():
            seen.setdefault(key, []).append(value)
    out = []
    for f in fields:
        if f.kind not in ("number", "integer") or f.low is None or f.high is None:
            continue
        if not f.path.startswith(GROUPS):
            continue
        out.append(Row(f.path, f.low, f.high, tuple(seen.get(f.path, ()))))
    return out, read


def _fmt(x: float) -> str:
    return f"{x:.4g}"


def table(found: list[Row], files: int) -> list[str]:
    lines = [
        "| field | schema accepts | training sessions hold | sessions | covered |",
        "|---|---|---|---:|---:|",
    ]
    for r in sorted(found, key=lambda r: (r.covered, r.path)):
        held = f"{_fmt(min(r.seen))} .. {_fmt(max(r.seen))}" if r.seen else "-"
        lines.append(
            f"| `{r.path}` | {_fmt(r.low)} .. {_fmt(r.high)} | {held} "
            f"| {len(r.seen)} of {files} | {100 * r.covered:.0f} % |"
        )
    return lines


def tempo_line(stretch: tuple[float, float], extra: tuple[float, float] | None) -> str:
    schema = next(f for f in schema_fields() if f.path == "script.tempo")
    assert schema.low is not None
    assert schema.high is not None
    ranges = [stretch] if extra is None else [stretch, extra]
    low, high = min(r[0] for r in ranges), max(r[1] for r in ranges)
    share = (np.log(high) - np.log(low)) / (np.log(schema.high) - np.log(schema.low))
    given = " and ".join(f"{a:g} .. {b:g}" for a, b in ranges)
    return (
        f"`script.tempo`: the schema accepts {schema.low:g} .. {schema.high:g}; training "
        f"stretched chunks to {given}: {100 * share:.0f} % of the schema's span in logarithm."
    )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python experiments/schema_vs_training.py")
    p.add_argument("--model", type=Path, default=DEFAULT_MODEL, help="its card names the files")
    p.add_argument("--files", type=Path, nargs="+", help="these sessions instead of the card's")
    p.add_argument("--tempo-range", type=float, nargs=2, default=(0.65, 1.3))
    p.add_argument("--tempo-extra-range", type=float, nargs=2, default=None)
    args = p.parse_args(argv)
    if args.files:
        files = list(args.files)
    else:
        try:
            card = open_step_model(args.model).card
        except Exception as exc:  # a model that does not open: one line
            p.error(f"{args.model}: {exc}")
        files = [ROOT / f for f in card.get("training_data", {}).get("files", [])]
        if not files:
            p.error(f"{args.model}: its card names no training files (give --files)")
    missing = [f for f in files if not f.is_file()]
    if missing:
        p.error(f"{len(missing)} of {len(files)} training files missing, e.g. {missing[0]}")
    found, read = rows(files, schema_fields())
    if not read:
        p.error("no training file carries a scene")
    print("\n".join(table(found, read)))
    extra = tuple(args.tempo_extra_range) if args.tempo_extra_range else None
    print()
    print(tempo_line(tuple(args.tempo_range), extra))
    return 0


if __name__ == "__main__":
    sys.exit(main())
