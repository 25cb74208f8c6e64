"""Scene files: who moves, what they do and which effects the sensors suffer.

A scene is a TOML file validated by pydantic; every mistake becomes one line
that names the file, the line and the field, e.g.
``scene.toml line 12: script[2].reps: Input should be greater than 0``::

    seed = 7            # everything random in the scene derives from it
    rate = 16.0         # frames per second of the session
    [subject]
    height_m = 1.75
    mass_kg = 70.0
    style_seed = 3      # the person's movement traits (scotti.sim.traits) ...
    strike = "heel"     # ... of which any can be given instead
    arch = "normal"     # optional: high, normal or flat (drawn when left out)
    [insole]
    model = "realistic" # or "ideal"; parameters may be overridden (sim/insole.py)
    [[script]]
    action = "squat"    # one of ACTIONS
    reps = 5            # or duration_s
    stand_s = 1.5       # quiet stand after it (labelled standing)
    [[effects]]
    name = "noise"      # see scotti.sim.effects.registry
    std_counts = 4

Instead of a script, a scene can ask for a lab session (``scotti.sim.session``)::

    [session]
    actions = ["squat", "walking"]  # default: every action
    minutes_per_action = 4.0        # or a table: {squat = 2.0, walking = 5.0}
    set_s = [30.0, 75.0]            # set lengths are drawn in this range
    rest_s = [5.0, 20.0]            # standing between sets
    seed = 3                        # the plan's draws; default: the scene's seed
"""

from __future__ import annotations

import dataclasses
import re
import tomllib
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator
from pydantic import model_validator as _model_validator
from scotti.models.contract import ACTIONS, FRAME_RATE_HZ
from scotti.models.set_edges import set_edges
from scotti.sim import SimError
from scotti.sim.actions import RECIPES, ActionSpec, Context, Place, Segment, stand
from scotti.sim.foot import BALL_WIDTH_RANGE, ArchType
from scotti.sim.insole import InsoleSpec
from scotti.sim.motion import Motion, Subject
from scotti.sim.session import SessionModel, session_segments
from scotti.sim.skeleton import Body, center_of_mass, pose_keypoints
from scotti.sim.traits import STRIKES, TRAIT_NAMES, TRAIT_RANGES

LEAD_IN_S = 1.0  # quiet stand before the first action
# Motions for session files are built at this multiple of the scene rate
# (8 x 16 Hz = 128 Hz) so that forces come from resolved accelerations; the
# writer samples them back to the frame rate (``writer.sim_input``).
PHYSICS_OVERSAMPLE = 8


class SceneError(SimError):
    """A scene file that cannot be read or does not validate (one line)."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


def _trait(name: str) -> Any:
    """An optional trait field, kept within the range the traits are drawn in."""
    r = TRAIT_RANGES[name]
    return Field(default=None, ge=r.low, le=r.high)


class SubjectModel(_Strict):
    """Body size and ``style_seed``; any trait given here replaces the drawn one."""

    height_m: float = Field(ge=1.2, le=2.2)
    mass_kg: float = Field(ge=30.0, le=200.0)
    foot_length_m: float | None = Field(default=None, ge=0.15, le=0.35)
    style_seed: int = 0
    strike: Literal[STRIKES] | None = None  # type: ignore[valid-type]
    walking_speed_mps: float | None = _trait("walking_speed_mps")
    step_length_ratio: float | None = _trait("step_length_ratio")
    step_width_m: float | None = _trait("step_width_m")
    stance_width_m: float | None = _trait("stance_width_m")
    toe_out_deg: float | None = _trait("toe_out_deg")
    toe_out_asymmetry_deg: float | None = _trait("toe_out_asymmetry_deg")
    strike_pitch_deg: float | None = _trait("strike_pitch_deg")
    stride_cv: float | None = _trait("stride_cv")
    speed_variability: float | None = _trait("speed_variability")
    asymmetry: float | None = _trait("asymmetry")
    depth: float | None = _trait("depth")
    lunge_depth: float | None = _trait("lunge_depth")
    squat_rep_s: float | None = _trait("squat_rep_s")
    lunge_rep_s: float | None = _trait("lunge_rep_s")
    tempo_variation: float | None = _trait("tempo_variation")
    depth_variation: float | None = _trait("depth_variation")
    rep_pause_s: float | None = _trait("rep_pause_s")
    fatigue_slowdown_per_min: float | None = _trait("fatigue_slowdown_per_min")
    fatigue_shallowing_per_min: float | None = _trait("fatigue_shallowing_per_min")
    cadence_spm: float | None = _trait("cadence_spm")
    push_off: float | None = _trait("push_off")
    # The foot's shape (scotti.sim.foot): None draws it from style_seed.
    arch: ArchType | None = None
    ball_width_ratio: float | None = Field(
        default=None, ge=BALL_WIDTH_RANGE[0], le=BALL_WIDTH_RANGE[1]
    )

    @classmethod
    def of(cls, subject: Subject) -> SubjectModel:
        """A drawn person's body and style seed (their traits are drawn again from it)."""
        return cls(
            height_m=subject.height_m,
            mass_kg=subject.mass_kg,
            foot_length_m=subject.foot_length,
            style_seed=subject.style_seed,
        )

    def subject(self) -> Subject:
        given = {n: getattr(self, n) for n in TRAIT_NAMES if getattr(self, n) is not None}
        return Subject(
            self.height_m,
            self.mass_kg,
            foot_length_m=self.foot_length_m,
            style_seed=self.style_seed,
            traits_given=given,
        )


class ScriptEntry(_Strict):
    """One action. ``depth`` applies to squat, lunge, jump and in-place walking
    (None: the subject's own); ``step_length_m`` to walking, backward and side
    walking and lunge (None: the person's own); ``step_height_m`` to step-up;
    ``direction`` to side walking; ``turn_deg`` to walking (the heading
    change, spread over the walk: an arc). ``vary`` draws speed changes
    (and for walking a walkway with turns) from the seed. Repetitions: one
    step for the walking actions, one full movement for the others."""

    action: Literal[ACTIONS]  # type: ignore[valid-type]
    reps: int | None = Field(default=None, gt=0, le=500)
    duration_s: float | None = Field(default=None, gt=0.0, le=3600.0)
    tempo: float = Field(default=1.0, ge=0.3, le=3.0)
    depth: float | None = Field(default=None, ge=0.0, le=1.0)
    step_length_m: float | None = Field(default=None, gt=0.0, le=1.5)
    step_height_m: float = Field(default=0.2, ge=0.05, le=0.5)
    direction: Literal["left", "right"] = "left"
    turn_deg: float = Field(default=0.0, ge=-1080.0, le=1080.0)
    vary: bool = False
    stand_s: float = Field(default=1.5, ge=0.0, le=600.0)

    @_model_validator(mode="after")
    def _reps_or_duration(self) -> ScriptEntry:
        if (self.reps is None) == (self.duration_s is None):
            msg = "give exactly one of reps and duration_s"
            raise ValueError(msg)
        return self

    def spec(self) -> ActionSpec:
        return ActionSpec(
            action=self.action,
            reps=self.reps,
            duration_s=self.duration_s,
            tempo=self.tempo,
            depth=self.depth,
            step_length_m=self.step_length_m,
            step_height_m=self.step_height_m,
            direction=self.direction,
            turn_rad=float(np.radians(self.turn_deg)),
            vary=self.vary,
        )


class Scene(_Strict):
    """A validated scene; ``effects`` stay raw tables until the effect registry checks them."""

    name: str = "scene"
    description: str = ""
    seed: int = 0
    rate: float = Field(default=FRAME_RATE_HZ, gt=0.0, le=1000.0)
    subject: SubjectModel
    script: list[ScriptEntry] = Field(default_factory=list)
    session: SessionModel | None = None
    insole: InsoleSpec = Field(default_factory=InsoleSpec)
    effects: list[dict[str, Any]] = Field(default_factory=list)

    @_model_validator(mode="after")
    def _script_or_session(self) -> Scene:
        if bool(self.script) == (self.session is not None):
            msg = "give either a script ([[script]] entries) or a [session], not both"
            raise ValueError(msg)
        return self

    @field_validator("effects")
    @classmethod
    def _effects_named(cls, effects: list[dict[str, Any]]) -> list[dict[str, Any]]:
        for effect in effects:
            if not isinstance(effect.get("name"), str):
                msg = "every effect needs a name"
                raise ValueError(msg)
        return effects

    @classmethod
    def from_toml_text(cls, text: str, name: str = "scene.toml") -> Scene:
        """Parse and validate; ``name`` is what error messages call the file."""
        try:
            raw = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise SceneError(_describe_toml(exc, name)) from None
        raw.setdefault("name", Path(name).stem)
        try:
            scene = cls.model_validate(raw)
        except ValidationError as exc:
            raise SceneError(_describe(exc, text, name)) from None
        scene.check_effects(text, name)
        return scene

    def check_effects(self, text: str = "", name: str = "scene.toml") -> None:
        """Validate the effect tables against the effect registry (when it exists)."""
        try:
            from scotti.sim.effects.registry import parse_effects
        except ImportError:  # the registry is optional for motion-only use
            return
        try:
            parse_effects(self.effects)
        except SimError as exc:
            index = _failing_effect(self.effects)
            line = _locate(text, ("effects", index)) if index is not None else None
            where = f"{name} line {line}" if line else name
            msg = f"{where}: effects[{index}]: {exc}" if index is not None else f"{where}: {exc}"
            raise SceneError(msg) from None

    def subject_model(self) -> Subject:
        return self.subject.subject()


def load_scene(path: str | Path) -> Scene:
    """Read and validate a scene file; ``SceneError`` with one line on any mistake."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        msg = f"{p}: cannot read scene ({exc.__class__.__name__}: {exc})"
        raise SceneError(msg) from None
    return Scene.from_toml_text(text, p.name)


def build_motion(scene: Scene, oversample: int = 1) -> Motion:
    """Run the script (lead-in stand, then each action followed by its stand) or the session,
    labelled by the convention (models/contract.py, "The labelling convention").

    ``oversample`` multiplies the scene's rate: 1 for kinematics and labels
    alone, ``PHYSICS_OVERSAMPLE`` for a motion whose forces are computed.
    """
    if oversample < 1:
        msg = f"oversample must be a positive integer, got {oversample}"
        raise SceneError(msg)
    subject = scene.subject_model()
    body = subject.body()
    rate = scene.rate * oversample
    rng = np.random.default_rng(np.random.SeedSequence([scene.seed, subject.style_seed]))
    ctx = Context(body, subject, rate, rng)
    if scene.session is not None:
        segments = session_segments(scene.session, ctx, scene.seed)
    else:
        segments = script_segments(ctx, scene.script)
    return with_set_edges(motion_from_segments(body, subject, rate, segments))


def script_segments(ctx: Context, script: list[ScriptEntry]) -> list[Segment]:
    """A script's segments: the lead-in stand, then each entry's recipe and its stand."""
    place = Place(0.0, 0.0, 0.0)
    segments = [stand(ctx, place, LEAD_IN_S)]
    for entry in script:
        segment = RECIPES[entry.action](ctx, entry.spec(), place)
        place = segment.end
        segments.append(segment)
        if entry.stand_s > 0:
            segments.append(stand(ctx, place, entry.stand_s))
    return segments


def with_set_edges(motion: Motion) -> Motion:
    """``motion`` with its sets' edges labelled by the convention (models/set_edges.py):
    a set keeps at most ``SET_EDGE_REST_S`` of still standing before its first movement
    and after its last, the rest is ``standing``; a squat or lunge set keeps exactly that
    second after its last movement, as a pause. Scripts and lab sessions alike."""
    action = set_edges(motion.pose_frame(), motion.action, motion.rate_hz)
    return dataclasses.replace(motion, action=action)


def motion_from_segments(
    body: Body, subject: Subject, rate_hz: float, segments: list[Segment]
) -> Motion:
    """Join segments and run the forward kinematics."""
    from scotti.sim.skeleton import PoseParams

    params = PoseParams.concatenate([s.params for s in segments])
    world = pose_keypoints(body, params)
    return Motion(
        rate_hz=rate_hz,
        world=world,
        com=center_of_mass(body, world),
        heading=params.heading.copy(),
        action=np.concatenate([s.action for s in segments]),
        subject=subject,
        ground_z=np.concatenate([s.ground_z for s in segments]),
    )


# --- errors with line numbers --------------------------------------------------


def _describe(exc: ValidationError, text: str, name: str) -> str:
    """The first validation error as ``name line N: field.path: message``."""
    error = exc.errors()[0]
    loc = tuple(error["loc"])
    path = _dotted(loc)
    line = _locate(text, loc)
    where = f"{name} line {line}" if line else name
    return f"{where}: {path}: {error['msg']}" if path else f"{where}: {error['msg']}"


def _describe_toml(exc: tomllib.TOMLDecodeError, name: str) -> str:
    """tomllib's message ``... (at line 3, column 5)`` as ``name line 3: ...``."""
    text = str(exc)
    found = re.search(r"\s*\(at line (\d+), column \d+\)", text)
    if found is None:
        return f"{name}: {text}"
    return f"{name} line {found.group(1)}: {text[: found.start()]}{text[found.end() :]}"


def _dotted(loc: tuple[Any, ...]) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out


_HEADER = re.compile(r"^\s*(\[\[?)\s*([A-Za-z0-9_.\-\"' ]+?)\s*\]\]?\s*(#.*)?$")
_KEY = re.compile(r"^\s*([A-Za-z0-9_\-\"']+)\s*=")


def _locate(text: str, loc: tuple[Any, ...]) -> int | None:
    """1-based line of the key ``loc`` points at (or of its table), None if not found.

    tomllib keeps no positions, so this walks the text: table headers
    ``[a]``, array-of-tables headers ``[[a]]`` (counted) and ``key =`` lines.
    """
    parts = [p for p in loc if isinstance(p, str | int)]
    table: tuple[Any, ...] = ()
    counts: dict[str, int] = {}
    best: int | None = None
    best_depth = -1
    for number, line in enumerate(text.splitlines(), start=1):
        header = _HEADER.match(line)
        if header and not _KEY.match(line):
            key = header.group(2).strip().strip("\"'")
            if header.group(1) == "[[":
                counts[key] = counts.get(key, -1) + 1
                table = (key, counts[key])
            else:
                table = (key,)
            depth = _match_depth(parts, table)
            if depth > best_depth:
                best, best_depth = number, depth
            continue
        key_match = _KEY.match(line)
        if key_match:
            full = (*table, key_match.group(1).strip("\"'"))
            depth = _match_depth(parts, full)
            if depth > best_depth:
                best, best_depth = number, depth
    return best if best_depth > 0 else None


def _match_depth(loc: list[Any], path: tuple[Any, ...]) -> int:
    """How many leading parts of ``path`` equal ``loc``; -1 when ``path`` goes astray."""
    if len(path) > len(loc) or list(loc[: len(path)]) != list(path):
        return -1
    return len(path)


def _failing_effect(effects: list[dict[str, Any]]) -> int | None:
    from scotti.sim.effects.registry import parse_effect

    for index, raw in enumerate(effects):
        try:
            parse_effect(raw, index)
        except SimError:
            return index
    return None
