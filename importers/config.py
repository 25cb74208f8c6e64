"""One import, described by one validated TOML file (plus CLI flags for simple cases).

Every mistake is one line naming the file, the line and the field, e.g.
``walk.toml line 9: pressure.rows: Input should be greater than 0``::

    subject = "p01"                 # who wore the insoles (subject-wise splits)
    [pressure]
    file = "insoles.csv"            # .csv, .npz or .h5/.hdf5, relative to this file
    rows = 16                       # the source grid of one foot
    cols = 8
    time_unit = "ms"
    [pressure.left]                 # orientation of each foot's grid as stored
    toes = "first_row"
    medial = "last_col"
    [counts]
    method = "per_kpa"              # counts | per_kpa | body_mass
    units_per_kpa = 12.5
    [keypoints]
    file = "pose.csv"
    set = "mediapipe33"             # coco_wholebody | mediapipe33 | body25 | custom
    up = "-y"                       # the source axis that points up, or "auto"
    [labels]
    segments = "segments.csv"       # start,end,action; or action = "squat"

Paths are relative to the TOML file's folder. importers/IMPORT.md has
every key.
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator
from scotti.importers.errors import InputError
from scotti.models.contract import ACTIONS, KEYPOINTS

TIME_UNITS: dict[str, float] = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
LENGTH_UNITS: dict[str, float] = {"m": 1.0, "cm": 0.01, "mm": 0.001}
UP_AXES = ("+x", "-x", "+y", "-y", "+z", "-z", "auto")


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class FootGrid(_Strict):
    """How one foot's grid lies in the source, as stored (before any change)."""

    toes: Literal["first_row", "last_row"] = "first_row"  # which row is at the toes
    medial: Literal["first_col", "last_col"] = "first_col"  # which column is at the big toe
    transpose: bool = False  # the source's rows run across the foot (swap first)
    outline: str | None = None  # 0/1 file (rows x cols, CSV or .npy): 0 = no taxel there


class PressureConfig(_Strict):
    file: str
    # auto: a vendor's export by its own header (importers/vendors/), else a table.
    format: Literal["auto", "table", "pedar", "fscan", "xsensor", "moticon", "gaitpdb"] = "auto"
    # Which insole a one-insole vendor file is, where it cannot say (F-Scan).
    foot: Literal["left", "right"] | None = None
    # A table's grid of one foot, as stored (vendor files say their own).
    rows: int | None = Field(default=None, gt=0, le=1024)
    cols: int | None = Field(default=None, gt=0, le=1024)
    time_unit: Literal["s", "ms", "us", "ns"] = "s"
    # CSV: the time column (name or 0-based index), the first taxel column, the
    # foot blocks in order and the order of taxels inside a block.
    time_column: str | int = 0
    first_column: int | None = Field(default=None, ge=0)  # None: right after the time column
    feet: tuple[Literal["left", "right"], Literal["left", "right"]] = ("left", "right")
    taxel_order: Literal["row_major", "column_major"] = "row_major"
    # .npz / HDF5: array names (HDF5: dataset paths). Either left and right
    # (N, rows, cols) or one ``frames`` (N, 2, rows, cols) in ``feet`` order.
    time_key: str = "time"
    left_key: str = "left"
    right_key: str = "right"
    frames_key: str | None = None
    # ActionNet-style recorders keep one stream per insole, each with its own
    # time stamps: then ``time_key`` is the left foot's and this the right's;
    # the right foot is interpolated onto the left foot's times.
    right_time_key: str | None = None
    left: FootGrid = FootGrid()
    right: FootGrid = FootGrid()

    @model_validator(mode="after")
    def _two_feet(self) -> PressureConfig:
        if self.feet[0] == self.feet[1]:
            msg = "feet must name left and right once each"
            raise ValueError(msg)
        return self


class CountsConfig(_Strict):
    """Another sensor's values onto our count scale (models/insole.py).

    counts: already counts like ours, times ``gain``. per_kpa: the source
    gives ``units_per_kpa`` units per kPa (1 for kPa, 1000 for Pa); kPa go
    through our transfer curve. body_mass: values proportional to pressure;
    the factor makes both feet carry ``mass_kg`` * g on average over
    ``stand_s`` (seconds from the first frame) with ``taxel_area_mm2`` each.
    """

    method: Literal["counts", "per_kpa", "body_mass"] = "counts"
    gain: float = Field(default=1.0, gt=0.0)
    units_per_kpa: float | None = Field(default=None, gt=0.0)
    mass_kg: float | None = Field(default=None, ge=10.0, le=300.0)
    stand_s: tuple[float, float] | None = None
    taxel_area_mm2: float | None = Field(default=None, gt=0.0)

    @model_validator(mode="after")
    def _method_needs(self) -> CountsConfig:
        needs = {
            "per_kpa": ("units_per_kpa",),
            "body_mass": ("mass_kg", "stand_s", "taxel_area_mm2"),
        }.get(self.method, ())
        missing = [name for name in needs if getattr(self, name) is None]
        if missing:
            msg = f"method {self.method!r} needs {', '.join(missing)}"
            raise ValueError(msg)
        if self.stand_s is not None and not 0.0 <= self.stand_s[0] < self.stand_s[1]:
            msg = "stand_s must be [start, end] seconds with 0 <= start < end"
            raise ValueError(msg)
        return self


class KeypointsConfig(_Strict):
    file: str
    set: Literal["coco_wholebody", "mediapipe33", "body25", "custom"]
    # custom: our keypoint name -> the source's keypoint name (or 0-based index).
    mapping: dict[str, str | int] | None = None
    mapping_file: str | None = None  # the same mapping in its own TOML file
    time_unit: Literal["s", "ms", "us", "ns"] = "s"
    time_offset_s: float = 0.0  # added to keypoint times to put them on the pressure clock
    time_column: str | int = 0
    time_key: str = "time"
    keypoints_key: str = "keypoints"  # .npz / HDF5: (N, K, 3) or (N, K, 4) with a score
    names_key: str = "names"  # .npz / HDF5, custom sets: the K names (optional)
    units: Literal["m", "cm", "mm"] = "m"
    up: Literal["+x", "-x", "+y", "-y", "+z", "-z", "auto"] = "+z"
    mirror: bool = False  # the source is mirrored (a left-handed frame, a mirrored video)
    floor_z: float | Literal["auto"] = "auto"  # the floor's height along ``up``, source units
    # plane: one floor for the whole recording (floor_z), refused when the feet are not on it
    # (hip-centred coordinates); feet: each frame stood on its lowest heel or toe.
    floor: Literal["plane", "feet"] = "plane"
    min_score: float = Field(default=0.0, ge=0.0, le=1.0)  # lower scores are masked
    max_gap_s: float = Field(default=0.25, gt=0.0)  # longer holes in tracking stay masked

    @field_validator("mapping")
    @classmethod
    def _our_names(cls, mapping: dict[str, str | int] | None) -> dict[str, str | int] | None:
        for name in mapping or {}:
            if name not in KEYPOINTS:
                msg = f"{name!r} is not one of our keypoints ({', '.join(KEYPOINTS)})"
                raise ValueError(msg)
        return mapping

    @model_validator(mode="after")
    def _custom_needs_mapping(self) -> KeypointsConfig:
        if self.set == "custom" and self.mapping is None and self.mapping_file is None:
            msg = "set 'custom' needs mapping or mapping_file"
            raise ValueError(msg)
        if self.floor == "feet" and self.floor_z != "auto":
            msg = "floor_z is the one floor of floor = 'plane'; floor = 'feet' finds it each frame"
            raise ValueError(msg)
        return self


class LabelsConfig(_Strict):
    segments: str | None = None  # CSV: start,end,action (header optional)
    action: str | None = None  # the whole recording is this one action
    time: Literal["relative", "absolute"] = "relative"  # from the first frame, or its clock
    time_unit: Literal["s", "ms", "us", "ns"] = "s"

    @field_validator("action")
    @classmethod
    def _known_action(cls, action: str | None) -> str | None:
        if action is not None and action not in ACTIONS:
            msg = f"{action!r} is not one of {', '.join(ACTIONS)}"
            raise ValueError(msg)
        return action

    @model_validator(mode="after")
    def _one_source(self) -> LabelsConfig:
        if (self.segments is None) == (self.action is None):
            msg = "give exactly one of segments and action"
            raise ValueError(msg)
        return self


class ImportConfig(_Strict):
    subject: str | None = None  # None: the output file's stem
    device: str = "imported"
    mass_kg: float | None = Field(default=None, ge=10.0, le=300.0)
    height_m: float | None = Field(default=None, ge=0.5, le=2.5)
    source_every_s: float = Field(default=1.0, ge=0.0)  # source frames kept for pictures; 0: none
    pressure: PressureConfig
    counts: CountsConfig = CountsConfig()
    keypoints: KeypointsConfig | None = None
    labels: LabelsConfig | None = None
    base_dir: str = "."  # where relative paths start (the TOML file's folder)

    def path(self, name: str) -> Path:
        p = Path(name)
        return p if p.is_absolute() else Path(self.base_dir) / p


def load_config(path: str | Path, overrides: dict[str, Any] | None = None) -> ImportConfig:
    """Read and validate an import TOML; ``overrides`` (from flags) win over its keys."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(p, f"cannot read ({exc.__class__.__name__})") from None
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        found = re.search(r"\(at line (\d+), column (\d+)\)", str(exc))
        problem = re.sub(r"\s*\(at line \d+, column \d+\)", "", str(exc))
        line = int(found.group(1)) if found else None
        raise InputError(p, problem, line=line) from None
    raw.setdefault("base_dir", str(p.parent))
    return config_from_dict(_merge(raw, overrides or {}), text=text, name=str(p))


def config_from_dict(raw: dict[str, Any], *, text: str = "", name: str = "flags") -> ImportConfig:
    try:
        return ImportConfig.model_validate(raw)
    except ValidationError as exc:
        error = exc.errors()[0]
        loc = tuple(error["loc"])
        field = ".".join(str(part) for part in loc)
        line = _locate(text, loc) if text else None
        problem = f"{field}: {error['msg']}" if field else str(error["msg"])
        raise InputError(name, problem, line=line) from None


def _merge(base: dict[str, Any], extra: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for key, value in extra.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _merge(out[key], value)
        else:
            out[key] = value
    return out


_TABLE = re.compile(r"^\s*\[\s*([A-Za-z0-9_.\-]+)\s*\]\s*(#.*)?$")
_KEY = re.compile(r"^\s*([A-Za-z0-9_\-]+)\s*=")


def _locate(text: str, loc: tuple[Any, ...]) -> int | None:
    """The line of the deepest key or table ``loc`` reaches in ``text`` (None: not there)."""
    want = [str(p) for p in loc if isinstance(p, str)]
    table: list[str] = []
    best, best_depth = None, 0
    for number, line in enumerate(text.splitlines(), start=1):
        header = _TABLE.match(line)
        if header:
            table = header.group(1).split(".")
            path = table
        else:
            key = _KEY.match(line)
            if not key:
                continue
            path = [*table, key.group(1)]
        if len(path) <= len(want) and want[: len(path)] == path and len(path) > best_depth:
            best, best_depth = number, len(path)
    return best


def load_mapping(path: Path) -> dict[str, str | int]:
    """A custom keypoint mapping file: ``our_name = "their name"`` (or an index) per line."""
    try:
        text = path.read_text(encoding="utf-8")
        raw = tomllib.loads(text)
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(path, f"cannot read ({exc.__class__.__name__})") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(path, str(exc)) from None
    table = raw.get("mapping", raw)
    prefix: tuple[str, ...] = ("mapping",) if "mapping" in raw else ()
    for name, value in table.items():
        if name not in KEYPOINTS:
            problem = f"{name!r} is not one of our keypoints ({', '.join(KEYPOINTS)})"
            raise InputError(path, problem, line=_locate(text, (*prefix, name)))
        if not isinstance(value, str | int) or isinstance(value, bool):
            line = _locate(text, (*prefix, name))
            raise InputError(path, f"{name}: give a name or an index", line=line)
    return dict(table)
