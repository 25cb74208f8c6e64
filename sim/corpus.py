"""A training corpus: N drawn subjects, each recorded as in a lab, one file each.

Subject ``i`` gets its own scene: a generated lab session
(``scotti.sim.session``) with every action for at least
``minutes_per_action`` minutes, cut into sets of 30-75 s in an order of its
own, standing 5-20 s between sets and walking or turning round between
spots; a seed derived from the corpus seed and ``i``; and either no effects
or a fresh draw of the ``realistic`` preset. The effects never touch the
motion's draws, so the clean and the realistic corpus of one seed hold the
same motions. ``manifest.json`` lists subjects, seeds, durations and files.
The insole's parameters are drawn per subject (``insole.draw_insole``), the
same in both copies. ``paces="wide"`` gives each person a walking speed drawn
uniformly over everything a scene accepts (0.5-1.65 m/s, ``sim.traits``), so
that about half of them walk as slowly as older people do, where the typical
population walks at 1.05-1.65 m/s. ``bodies="wide"`` draws each person's
height, mass and foot length again over what the scene schema accepts
(``wide_body``), where the typical population is adults of 1.50-1.95 m.
``gaits="wide"`` draws each person's push-off (how far the foot rolls over
its toes at toe-off) and the foot's pitch at touch-down uniformly over what
a scene accepts (``wide_gait``): shuffling walkers who land flat and barely
lift their heels, where the typical population pushes off alike and mostly
lands on the heel at 20 deg. ``effects="wide"`` gives each person the
realistic draw with three effects drawn again over everything a scene accepts
(``sim.effects.wide``): a hysteresis up to 0.8, a radio link that stays bad,
one insole up to a second late.
The feet's shape and placement come from the subject's style seed and the
session's seed (``foot.draw_feet``). The same arguments give the same files, byte for byte.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, Final, Literal

import numpy as np
from scotti.models.contract import ACTIONS
from scotti.sim.actions import EXERCISES
from scotti.sim.effects.registry import parse_effects, realistic_effects
from scotti.sim.effects.wide import wide_effects
from scotti.sim.field_range import field_range
from scotti.sim.foot import draw_feet
from scotti.sim.insole import InsoleSpec, InsoleSpread, draw_insole
from scotti.sim.motion import Subject
from scotti.sim.scene import PHYSICS_OVERSAMPLE, Scene, SubjectModel, build_motion
from scotti.sim.session import SessionModel
from scotti.sim.subjects import draw_subjects
from scotti.sim.traits import TRAIT_RANGES
from scotti.sim.writer import RenderReport, sim_input, write_session

EffectsPreset = Literal["realistic", "none", "mixed", "wide"]
MIXED_CLEAN_SHARE: Final = 1 / 3  # of subjects without effects in a "mixed" corpus
SET_S: Final = (30.0, 75.0)  # length of one set
REST_S: Final = (5.0, 20.0)  # standing between sets
MANIFEST: Final = "manifest.json"
PaceSpread = Literal["typical", "wide"]
BodySpread = Literal["typical", "wide"]
GaitSpread = Literal["typical", "wide"]
# A wide body: body-mass index and foot length (a share of height) drawn uniformly in
# these, then kept within the schema's mass and foot length (sim/scene.py SubjectModel).
WIDE_BMI: Final = (16.0, 42.0)
WIDE_FOOT_RATIO: Final = (0.125, 0.17)


def wide_body(rng: np.random.Generator) -> dict[str, float]:
    """Height uniform over the schema's whole range (1.2-2.2 m), a body-mass index of
    16-42 and a foot of 0.125-0.17 x height, mass and foot kept within the schema:
    children's and very tall people's bodies, thin and heavy, short and long feet."""
    height = float(rng.uniform(*field_range(SubjectModel, "height_m")))
    bmi = float(rng.uniform(*WIDE_BMI))
    ratio = float(rng.uniform(*WIDE_FOOT_RATIO))
    mass = float(np.clip(bmi * height**2, *field_range(SubjectModel, "mass_kg")))
    foot = float(np.clip(ratio * height, *field_range(SubjectModel, "foot_length_m")))
    return {
        "height_m": round(height, 3),
        "mass_kg": round(mass, 1),
        "foot_length_m": round(foot, 4),
    }


def wide_gait(rng: np.random.Generator) -> dict[str, float]:
    """Push-off and the foot's pitch at touch-down, each uniform over the range a scene
    accepts (sim/traits.py): from a shuffle (flat landing, heel barely rising) to the
    typical heel strike and roll-off, and beyond to forefoot landings."""
    values = {}
    for name in ("push_off", "strike_pitch_deg"):
        r = TRAIT_RANGES[name]
        values[name] = round(float(rng.uniform(r.low, r.high)), 4)
    return values


def subject_scene(
    index: int,
    subject: Subject,
    *,
    corpus_seed: int,
    minutes_per_action: float,
    effects: EffectsPreset,
    insoles: InsoleSpread = "typical",
    paces: PaceSpread = "typical",
    bodies: BodySpread = "typical",
    gaits: GaitSpread = "typical",
) -> Scene:
    """The scene of one corpus subject (a lab session of all actions, derived seed, effects).

    ``mixed`` effects: a third of the subjects (a coin of their own) are clean,
    the rest get the draw a ``realistic`` corpus gives them, so that a model
    meets both a clean and a noisy transport of the same population. ``wide``
    effects: that realistic draw with three effects drawn again over the whole
    range a scene accepts (``sim.effects.wide``); nobody is clean.
    """
    seed = int(np.random.SeedSequence([corpus_seed, index]).generate_state(1)[0])
    raw_effects: list[dict[str, Any]] = []
    clean = effects == "none" or (
        effects == "mixed"
        and np.random.default_rng([corpus_seed, index, 0xC1]).random() < MIXED_CLEAN_SHARE
    )
    if effects == "wide":  # the realistic draw, a few effects drawn again over the schema
        raw_effects = wide_effects(
            np.random.default_rng([corpus_seed, index, 0xEF]),
            np.random.default_rng([corpus_seed, index, 0xE1DE]),
        )
    elif not clean:
        raw_effects = realistic_effects(np.random.default_rng([corpus_seed, index, 0xEF]))
    # Each subject wears their own pair of insoles, drawn whatever the effects:
    # the clean copy differs from the realistic one by the effects alone.
    drawn = draw_insole(np.random.default_rng([corpus_seed, index, 0x15]), insoles)
    insole = InsoleSpec.model_validate(drawn.as_dict())
    person = SubjectModel.of(subject)
    if paces == "wide":  # a generator of its own: the other draws stay as they were
        speed = TRAIT_RANGES["walking_speed_mps"]
        pace = np.random.default_rng([corpus_seed, index, 0x9ACE]).uniform(speed.low, speed.high)
        person = person.model_copy(update={"walking_speed_mps": float(pace)})
    if bodies == "wide":  # a generator of its own too: the style seed and the rest stay
        body = wide_body(np.random.default_rng([corpus_seed, index, 0xB0D1]))
        person = person.model_copy(update=body)
    if gaits == "wide":  # and one for the gait: every other draw stays
        gait = wide_gait(np.random.default_rng([corpus_seed, index, 0x6A17]))
        person = person.model_copy(update=gait)
    return Scene(
        name=f"subject-{index:03d}",
        description=(
            f"corpus subject {index}: lab session, every action for at least "
            f"{minutes_per_action} min in sets, standing and transitions between"
        ),
        seed=seed,
        subject=person,
        session=SessionModel(
            actions=list(EXERCISES),
            minutes_per_action=minutes_per_action,
            set_s=SET_S,
            rest_s=REST_S,
        ),
        insole=insole,
        effects=raw_effects,
    )


def render_scene(
    scene: Scene,
    path: str | os.PathLike[str],
    seed: int | None = None,
    subject_id: str | None = None,
) -> RenderReport:
    """Motion, pressure and effects of ``scene`` into the session file ``path``.

    ``subject_id`` goes into the header's subject as "id" (training splits
    by it); without it readers fall back to the file name.
    """
    motion = build_motion(scene, PHYSICS_OVERSAMPLE)
    subject: dict[str, Any] = motion.subject.as_dict()
    if subject_id is not None:
        subject["id"] = subject_id
    session_seed = scene.seed if seed is None else seed
    feet = draw_feet(
        motion.subject.foot_length,
        subject_seed=scene.subject.style_seed,
        session_seed=session_seed,
        arch=scene.subject.arch,
        ball_width_ratio=scene.subject.ball_width_ratio,
    )
    return write_session(
        path,
        sim_input(motion),
        seed=session_seed,
        effects=parse_effects(scene.effects),
        scene=scene.model_dump(mode="json"),
        subject=subject,
        feet=feet,
        insole=scene.insole.resolved(),
    )


def write_corpus(
    out_dir: str | os.PathLike[str],
    *,
    subjects: int,
    seed: int,
    minutes_per_action: float,
    effects: EffectsPreset,
    first: int = 0,
    insoles: InsoleSpread = "typical",
    paces: PaceSpread = "typical",
    bodies: BodySpread = "typical",
    gaits: GaitSpread = "typical",
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Render every subject's session into ``out_dir`` and write the manifest.

    ``first`` skips that many people of the seed's population: subjects
    ``first .. first + subjects - 1``, the same people (names, seeds, effects,
    insoles) as in a corpus of ``first + subjects`` drawn from the same seed, so
    a corpus can be extended with new training subjects without touching the old.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    entries: list[dict[str, Any]] = []
    population = draw_subjects(first + subjects, seed)
    for i, subject in enumerate(population[first:], start=first):
        scene = subject_scene(
            i,
            subject,
            corpus_seed=seed,
            minutes_per_action=minutes_per_action,
            effects=effects,
            insoles=insoles,
            paces=paces,
            bodies=bodies,
            gaits=gaits,
        )
        name = f"{scene.name}.ses"
        started = time.perf_counter()
        report = render_scene(scene, out / name, subject_id=scene.name)
        elapsed = time.perf_counter() - started
        entries.append(
            {
                "id": scene.name,
                "file": name,
                "seed": scene.seed,
                "subject": scene.subject.subject().as_dict(),  # with a given pace
                "actions": list(ACTIONS),
                "duration_s": report.duration_s,
                "frames": report.frames,
                "effects": [e["name"] for e in scene.effects],
                "insole": scene.insole.resolved().as_dict(),
                "bytes": (out / name).stat().st_size,
            }
        )
        if progress is not None:
            progress(
                f"{name} ({i + 1 - first}/{subjects}): {report.duration_s / 60:.1f} min, "
                f"{report.frames} frames, rendered in {elapsed:.1f} s "
                f"({report.duration_s / max(elapsed, 1e-9):.0f}x real time)"
            )
    manifest = {
        "kind": "scotti-sim-corpus",
        "seed": seed,
        "subjects": subjects,
        "first_subject": first,
        "minutes_per_action": minutes_per_action,
        "effects": effects,
        "insoles": insoles,
        "paces": paces,
        "bodies": bodies,
        "gaits": gaits,
        "total_duration_s": sum(e["duration_s"] for e in entries),
        "sessions": entries,
    }
    (out / MANIFEST).write_text(json.dumps(manifest, indent=2, sort_keys=True) + "\n")
    return manifest
