"""A training corpus: N drawn subjects, each doing every action of the contract, one file each.

Subject ``i`` gets its own scene: every action in the contract's order for
``minutes_per_action`` minutes with a short stand between, a seed derived
from the corpus seed and ``i``, and either no effects or a fresh draw of the
``realistic`` preset. ``manifest.json`` lists subjects, seeds, durations and
files; the same arguments give the same files, byte for byte.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any, Final, Literal

import numpy as np
from scotti.models.contract import ACTIONS
from scotti.sim.effects.registry import parse_effects, realistic_effects
from scotti.sim.motion import Subject
from scotti.sim.scene import Scene, ScriptEntry, SubjectModel, build_motion
from scotti.sim.subjects import draw_subjects
from scotti.sim.writer import RenderReport, sim_input, write_session

EffectsPreset = Literal["realistic", "none"]
STAND_BETWEEN_S: Final = 2.0
MANIFEST: Final = "manifest.json"


def subject_scene(
    index: int,
    subject: Subject,
    *,
    corpus_seed: int,
    minutes_per_action: float,
    effects: EffectsPreset,
) -> Scene:
    """The scene of one corpus subject (all actions, derived seed, effects preset)."""
    seed = int(np.random.SeedSequence([corpus_seed, index]).generate_state(1)[0])
    raw_effects: list[dict[str, Any]] = []
    if effects == "realistic":
        raw_effects = realistic_effects(np.random.default_rng([corpus_seed, index, 0xEF]))
    return Scene(
        name=f"subject-{index:03d}",
        description=f"corpus subject {index}: all actions, {minutes_per_action} min each",
        seed=seed,
        subject=SubjectModel(
            height_m=subject.height_m,
            mass_kg=subject.mass_kg,
            foot_length_m=subject.foot_length,
            style_seed=subject.style_seed,
        ),
        script=[
            ScriptEntry(action=a, duration_s=minutes_per_action * 60.0, stand_s=STAND_BETWEEN_S)
            for a in ACTIONS
        ],
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
    motion = build_motion(scene)
    subject: dict[str, Any] = motion.subject.as_dict()
    if subject_id is not None:
        subject["id"] = subject_id
    return write_session(
        path,
        sim_input(motion),
        seed=scene.seed if seed is None else seed,
        effects=parse_effects(scene.effects),
        scene=scene.model_dump(mode="json"),
        subject=subject,
    )


def write_corpus(
    out_dir: str | os.PathLike[str],
    *,
    subjects: int,
    seed: int,
    minutes_per_action: float,
    effects: EffectsPreset,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Render every subject's session into ``out_dir`` and write the manifest."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    entries: list[dict[str, Any]] = []
    for i, subject in enumerate(draw_subjects(subjects, seed)):
        scene = subject_scene(
            i, subject, corpus_seed=seed, minutes_per_action=minutes_per_action, effects=effects
        )
        name = f"{scene.name}.ses"
        report = render_scene(scene, out / name, subject_id=scene.name)
        entries.append(
            {
                "id": scene.name,
                "file": name,
                "seed": scene.seed,
                "subject": subject.as_dict(),
                "actions": list(ACTIONS),
                "duration_s": report.duration_s,
                "frames": report.frames,
                "effects": [e["name"] for e in scene.effects],
                "bytes": (out / name).stat().st_size,
            }
        )
        if progress is not None:
            progress(f"{name}: {report.duration_s:.0f} s, {report.frames} frames")
    manifest = {
        "kind": "scotti-sim-corpus",
        "seed": seed,
        "subjects": subjects,
        "minutes_per_action": minutes_per_action,
        "effects": effects,
        "total_duration_s": sum(e["duration_s"] for e in entries),
        "sessions": entries,
    }
    (out / MANIFEST).write_text(json.dumps(manifest, indent=2, sort_keys=True) + "\n")
    return manifest
