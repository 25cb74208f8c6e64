"""The coverage grid: every field a scene may set, read from the scene schema, and
the values each is swept over (its schema minimum and maximum, and
``INTERIOR_LEVELS`` points between them, so that where along its range a field
stops holding can be read; the scene's default is the baseline every row is
measured against).

A field is swept unless ``SKIPPED`` names it with a reason; a field without a
range in the schema (an unbounded number) needs its values in ``NOT_RANGE``,
also with a reason. ``tests/test_experiments_coverage.py`` fails when a field of
the schema is neither swept over its whole range nor declared here, so a new
field or a changed range shows up.
"""

from __future__ import annotations

import hashlib
import json
import types
import typing
from dataclasses import dataclass
from typing import Any, Final, Literal

import numpy as np
from annotated_types import Ge, Gt, Le, Lt
from pydantic import BaseModel
from scotti.models.contract import ACTIONS
from scotti.sim.effects.registry import EFFECT_MODELS, realistic_effects
from scotti.sim.insole import InsoleSpec
from scotti.sim.scene import Scene, ScriptEntry, SubjectModel
from scotti.sim.subjects import draw_subjects

COVERAGE_SEED: Final = 37  # the people of the grid (issue 37); any seed, fixed for reruns
# An open bound (gt/lt) is approached to this share of the field's span.
OPEN_BOUND_SHARE: Final = 1e-4

# Fields of the schema that are not swept, and why.
SKIPPED: Final[dict[str, str]] = {
    "name": "a label: nothing simulated depends on it",
    "description": "a label: nothing simulated depends on it",
    "seed": "every person of a cell has a scene seed of their own (--people)",
    "subject.style_seed": "every person of a cell has a style seed of their own (--people)",
    "script.action": "the grid's other axis: every parameter is swept for every action",
    "script.reps": "each cell runs its action for --seconds (duration_s), so cells compare",
    "script.duration_s": "each cell runs its action for --seconds, the same in every cell",
    "session": "a generated lab session instead of a script: scored as "
    "sim/scenes/lab-session.toml in the scene-file section",
}

# Fields swept over other values than the schema's extremes: (reason, values).
NOT_RANGE: Final[dict[str, tuple[str, tuple[Any, ...]]]] = {
    "rate": (
        "the renderer takes multiples of 16 Hz only and always writes 16 Hz frames (the "
        "contract's rate); a higher scene rate only refines the physics step, so the "
        "schema's (0, 1000] is swept at the next renderable rate",
        (32.0,),
    ),
    "effects.unplug.start_s": (
        "no upper bound: an unplug that starts after the session has ended does nothing",
        (0.0,),
    ),
}

# Values swept besides a field's extremes (reason, values): points measured before.
EXTRA_VALUES: Final[dict[str, tuple[str, tuple[Any, ...]]]] = {
    "insole.threshold_kpa": ("a softer insole measured in issue 37", (45.0,)),
    "insole.p_half_kpa": ("a softer insole measured in issue 37", (450.0,)),
    "insole.gain_sigma": ("the wider gain spread measured in issue 37", (0.45,)),
    "script.step_length_m": (
        "the steps people take (the interior points of a range from 0 are spaced by ratio)",
        (0.3, 0.6, 0.9),
    ),
    "insole.saturation_counts": (
        "where real amplifiers rail (the realistic insole draws 3000-4095 counts, "
        "sim/insole.py): the interior points of so wide a range are spaced by ratio",
        (2048.0, 3000.0),
    ),
}

# Points strictly inside a ranged field's span, spaced evenly, or by equal ratios where
# the span covers GEOMETRIC_RATIO or more (a probability from 1e-4 to 1, a time constant
# from milliseconds to an hour): with the ends, five points show where a field holds.
INTERIOR_LEVELS: Final = 3
GEOMETRIC_RATIO: Final = 20.0
# Ranged fields swept at their ends only (reason).
NO_INTERIOR: Final[dict[str, str]] = {
    "script.stand_s": "each value is minutes of standing for every person of a cell; the ends "
    "(no stand, ten minutes) say what the stand does",
    "effects.unplug.duration_s": "an unplug longer than the cell's session is the same cell; "
    "the ends (a blink, a day) say what an unplug does",
}

# Other parameters of the same effect a swept one needs to matter at all (reason, values).
WITH: Final[dict[str, tuple[str, dict[str, Any]]]] = {
    "effects.line_corruption.garbage_min_bytes": (
        "burst sizes matter only when bursts come (default garbage_per_s is 0)",
        {"garbage_per_s": 1.0},
    ),
    "effects.line_corruption.garbage_max_bytes": (
        "burst sizes matter only when bursts come (default garbage_per_s is 0)",
        {"garbage_per_s": 1.0},
    ),
}

REALISTIC: Final = "realistic"  # the value of ``effects`` that draws the corpus preset


@dataclass(frozen=True)
class SchemaField:
    """One field a scene may set, as the schema declares it."""

    path: str  # "subject.height_m", "script.tempo", "insole.gain_sigma", "effects.noise.std_counts"
    kind: str  # "number", "integer", "choice", "bool", "effects" (which effects), "other"
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    choices: tuple[Any, ...] = ()
    default: Any = None  # None: given by the person or drawn


def schema_fields() -> list[SchemaField]:
    """Every field of a scene (subject, script entry, insole, each effect and its parameters)."""
    out: list[SchemaField] = []
    for name, info in Scene.model_fields.items():
        if name == "subject":
            out += _model_fields(SubjectModel, "subject.")
        elif name == "script":
            out += _model_fields(ScriptEntry, "script.")
        elif name == "insole":
            out += _model_fields(InsoleSpec, "insole.")
        elif name == "effects":
            out.append(SchemaField("effects", "effects", choices=(REALISTIC, *EFFECT_MODELS)))
            for effect, model in EFFECT_MODELS.items():
                out += _model_fields(model, f"effects.{effect}.")
        else:
            out.append(_field(name, info.annotation, info.metadata, _default(info)))
    return out


def _model_fields(model: type[BaseModel], prefix: str) -> list[SchemaField]:
    return [
        _field(prefix + n, f.annotation, f.metadata, _default(f))
        for n, f in model.model_fields.items()
    ]


def _default(info: Any) -> Any:
    return None if info.is_required() else info.get_default(call_default_factory=True)


def _field(path: str, annotation: Any, metadata: list[Any], default: Any) -> SchemaField:
    """The kind and range of one field from its annotation and its pydantic constraints."""
    inner = _without_none(annotation)
    if typing.get_origin(inner) is Literal:
        return SchemaField(path, "choice", choices=typing.get_args(inner), default=default)
    if inner is bool:
        return SchemaField(path, "bool", choices=(False, True), default=default)
    if inner in (int, float):
        low = high = None
        low_open = high_open = False
        for m in metadata:
            if isinstance(m, Ge):
                low = float(m.ge)  # type: ignore[arg-type]
            elif isinstance(m, Gt):
                low, low_open = float(m.gt), True  # type: ignore[arg-type]
            elif isinstance(m, Le):
                high = float(m.le)  # type: ignore[arg-type]
            elif isinstance(m, Lt):
                high, high_open = float(m.lt), True  # type: ignore[arg-type]
        kind = "integer" if inner is int else "number"
        return SchemaField(path, kind, low, high, low_open, high_open, default=default)
    return SchemaField(path, "other", default=default)


def _without_none(annotation: Any) -> Any:
    """``X | None`` -> ``X``; anything else as it is."""
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(annotation) if a is not type(None)]
        return args[0] if len(args) == 1 else annotation
    return annotation


def extremes(field: SchemaField) -> tuple[Any, Any] | None:
    """The smallest and largest value the schema accepts (an open bound approached to
    ``OPEN_BOUND_SHARE`` of the span); None when the field has no range."""
    if field.kind not in ("number", "integer") or field.low is None or field.high is None:
        return None
    span = field.high - field.low
    low = field.low + OPEN_BOUND_SHARE * span if field.low_open else field.low
    high = field.high - OPEN_BOUND_SHARE * span if field.high_open else field.high
    if field.kind == "integer":
        return int(np.ceil(low if not field.low_open else field.low + 1)), int(
            np.floor(high if not field.high_open else field.high - 1)
        )
    return round(low, 6), round(high, 6)


class GridError(Exception):
    """A field of the schema the grid does not know how to sweep (one line)."""


@dataclass(frozen=True)
class Parameter:
    """A swept field and its values (the baseline, the scene's default, is not among them)."""

    path: str
    values: tuple[Any, ...]
    default: Any = None  # the schema's default (None: drawn per person, or none at all)

    @property
    def group(self) -> str:
        """subject, script, insole, effects or scene: how the doc groups the rows."""
        head = self.path.split(".", 1)[0]
        return head if head in ("subject", "script", "insole", "effects") else "scene"

    @property
    def moves_only(self) -> bool:
        """Whether the field acts on the motion alone (movement traits and script fields):
        a value that leaves an action's motion as it was is not simulated again."""
        if self.path.startswith("script."):
            return True
        name = self.path.removeprefix("subject.")
        return self.path.startswith("subject.") and name in _TRAITS


# The subject's body (size, foot shape): it changes the pressure whatever the motion.
_BODY: Final = frozenset(
    {"height_m", "mass_kg", "foot_length_m", "style_seed", "arch", "ball_width_ratio"}
)
# Movement traits (strike pattern included): they act on the motion only.
_TRAITS: Final = frozenset(n for n in SubjectModel.model_fields if n not in _BODY)


def parameters(fields: list[SchemaField] | None = None) -> list[Parameter]:
    """The swept parameters in schema order; GridError for a field with no rule."""
    out = []
    for field in schema_fields() if fields is None else fields:
        if field.path in SKIPPED:
            continue
        values = sweep_values(field)
        out.append(Parameter(field.path, values, field.default))
    return out


def sweep_values(field: SchemaField) -> tuple[Any, ...]:
    """A field's values: its extremes (or its declared values) and any extra points."""
    if field.path in NOT_RANGE:
        values: tuple[Any, ...] = NOT_RANGE[field.path][1]
    elif field.kind in ("choice", "bool"):
        values = tuple(c for c in field.choices if c != field.default)
    elif field.kind == "effects":
        return field.choices  # the realistic preset, then each effect at its defaults
    else:
        ends = extremes(field)
        if ends is None:
            msg = (
                f"scene field {field.path} has no range in the schema: declare its values in "
                "NOT_RANGE or skip it in SKIPPED (experiments/coverage_grid.py), with a reason"
            )
            raise GridError(msg)
        inside = () if field.path in NO_INTERIOR else interior(field.kind, *ends)
        # An extreme that is the default is the baseline's cell (or, for an effect's
        # parameter, the cell of that effect at its defaults): not a cell of its own.
        values = tuple(v for v in dict.fromkeys((*ends, *inside)) if v != field.default)
    extra = EXTRA_VALUES.get(field.path, ("", ()))[1]
    return tuple(sorted(dict.fromkeys((*values, *extra)), key=_order))


def interior(kind: str, low: float, high: float, levels: int = INTERIOR_LEVELS) -> tuple[Any, ...]:
    """``levels`` points strictly between ``low`` and ``high``, evenly spaced, or by equal
    ratios where ``high / low`` is ``GEOMETRIC_RATIO`` or more; three significant digits
    (integers for an integer field), so a cell's label reads as a value one would type."""
    steps = np.arange(1, levels + 1) / (levels + 1)
    if low > 0 and high / low >= GEOMETRIC_RATIO:
        points = low * (high / low) ** steps
    else:
        points = low + (high - low) * steps
    if kind == "integer":
        inside = [int(np.rint(p)) for p in points]
    else:
        inside = [float(f"{p:.3g}") for p in points]
    return tuple(p for p in dict.fromkeys(inside) if low < p < high)


def _order(value: Any) -> tuple[int, Any]:
    return (0, value) if isinstance(value, int | float) else (1, str(value))


# --- people and scenes ------------------------------------------------------------


@dataclass(frozen=True)
class Person:
    """One simulated person of every cell: body, style and scene seed."""

    index: int
    height_m: float
    mass_kg: float
    style_seed: int
    seed: int


def people(count: int, seed: int = COVERAGE_SEED) -> list[Person]:
    """``count`` people drawn like a corpus's (sim/subjects.py), with scene seeds of their own."""
    drawn = draw_subjects(count, seed)
    return [
        Person(
            k,
            s.height_m,
            s.mass_kg,
            s.style_seed,
            int(np.random.SeedSequence([seed, k]).generate_state(1)[0]),
        )
        for k, s in enumerate(drawn)
    ]


@dataclass(frozen=True)
class Cell:
    """One action with one parameter at one value (``path`` None: the baseline)."""

    action: str
    path: str | None = None
    value: Any = None

    @property
    def label(self) -> str:
        return "baseline" if self.path is None else f"{self.path} = {_show(self.value)}"

    def scene(self, person: Person, seconds: float) -> dict[str, Any]:
        """The scene of this cell for one person, as a scene file's tables."""
        raw: dict[str, Any] = {
            "name": f"coverage-{self.action}-p{person.index}",
            "seed": person.seed,
            "subject": {
                "height_m": person.height_m,
                "mass_kg": person.mass_kg,
                "style_seed": person.style_seed,
            },
            "script": [{"action": self.action, "duration_s": seconds}],
        }
        if self.path is None:
            return raw
        head, _, rest = self.path.partition(".")
        if head == "subject":
            raw["subject"][rest] = self.value
        elif head == "script":
            raw["script"][0][rest] = self.value
        elif head == "insole":
            raw["insole"] = {rest: self.value}
        elif head == "effects":
            raw["effects"] = _effects(rest, self.value, person)
        else:
            raw[head] = self.value
        return raw


def _effects(rest: str, value: Any, person: Person) -> list[dict[str, Any]]:
    if not rest:  # the effects list itself: the realistic preset or one effect at its defaults
        if value == REALISTIC:
            rng = np.random.default_rng([COVERAGE_SEED, person.index, 0xEF])
            return realistic_effects(rng)
        return [{"name": value}]
    effect, _, param = rest.partition(".")
    companions = WITH.get(f"effects.{rest}", ("", {}))[1]
    return [{"name": effect, **companions, param: value}]


def _show(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:g}"
    return str(value)


def cells(actions: tuple[str, ...] = ACTIONS, params: list[Parameter] | None = None) -> list[Cell]:
    """Baselines first, then parameter by parameter (so a partial run has whole rows)."""
    swept = parameters() if params is None else params
    out = [Cell(a) for a in actions]
    for p in swept:
        out += [Cell(a, p.path, v) for v in p.values for a in actions]
    return out


def digest(value: Any) -> str:
    """A short stable hash of a JSON-able value (cache keys)."""
    text = json.dumps(value, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]
