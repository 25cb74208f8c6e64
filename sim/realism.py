"""The simulator against the literature: ``scotti sim realism`` writes sim/REALISM.md.

A fixed set of drawn subjects (``draw_subjects(count, seed)``) each does a
short scene of every action, built at the physics rate
(``PHYSICS_OVERSAMPLE`` x 16 Hz). Each figure of
:func:`scotti.sim.physics_figures.measure` is taken per subject and set
beside its published range (:mod:`scotti.sim.realism_refs`); a figure is
inside when every subject's value is. The doc also carries the spread of
every drawn trait over a large population (:func:`subjects.trait_spread`)
and one picture per action made by ``scotti sim render``.

Measuring is separate from writing: :func:`measure_population` returns
numbers, :func:`realism_markdown` formats them, the CLI writes the files.
"""

from __future__ import annotations

import math
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np
from scotti.models.contract import ACTIONS
from scotti.sim.foot import ARCH_TYPES, Feet, draw_feet
from scotti.sim.loads import FootLoads, foot_loads
from scotti.sim.motion import Motion, Subject
from scotti.sim.physics_figures import measure
from scotti.sim.plantar import REGION_NAMES
from scotti.sim.pressure import PressureRenderer
from scotti.sim.realism_refs import REFERENCES, Reference
from scotti.sim.scene import PHYSICS_OVERSAMPLE, Scene, ScriptEntry, SubjectModel, build_motion
from scotti.sim.subjects import PopulationSpread, draw_subjects, trait_spread

DEFAULT_SUBJECTS: Final = 8
DEFAULT_SEED: Final = 7
# The measuring scene: every action once, enough repetitions for medians.
_SCRIPT: Final = (
    ("walking", 10),
    ("backward_walking", 8),
    ("side_walking", 4),
    ("jump", 4),
    ("step_up", 3),
    ("squat", 4),
)


@dataclass(frozen=True)
class Row:
    """One quantity: its reference and the value per subject."""

    reference: Reference
    values: tuple[float, ...]

    @property
    def measured(self) -> tuple[float, ...]:
        return tuple(v for v in self.values if math.isfinite(v))

    @property
    def inside(self) -> bool:
        got = self.measured
        if not got:
            return False
        if self.reference.judge == "median":
            return self.reference.contains(float(np.median(got)))
        return all(self.reference.contains(v) for v in got)


@dataclass(frozen=True)
class Realism:
    """Everything the doc says: per-quantity rows, the subjects, the population spread."""

    rows: tuple[Row, ...]
    subjects: tuple[Subject, ...]
    seed: int
    spread: PopulationSpread
    feet: tuple[Feet, ...]
    # Per subject: walking's share of the force-time integral per plantar region.
    walking_shares: tuple[dict[str, float], ...]

    @property
    def measured_rows(self) -> tuple[Row, ...]:
        """The rows some subject gave a value for (a strike pattern may not be drawn)."""
        return tuple(r for r in self.rows if r.measured)


def measuring_scene(subject: Subject, seed: int) -> Scene:
    """The short scene of every measured action for one subject."""
    return Scene(
        name="realism",
        seed=seed,
        subject=SubjectModel.of(subject),
        script=[ScriptEntry(action=a, reps=n, stand_s=2.0) for a, n in _SCRIPT],
    )


def measure_population(
    count: int = DEFAULT_SUBJECTS,
    seed: int = DEFAULT_SEED,
    progress: Callable[[str], None] | None = None,
) -> Realism:
    """Build and measure the measuring scene of ``count`` drawn subjects."""
    subjects = tuple(draw_subjects(count, seed))
    figures: list[dict[str, float]] = []
    feet: list[Feet] = []
    shares: list[dict[str, float]] = []
    for i, subject in enumerate(subjects):
        scene = measuring_scene(subject, seed + i)
        motion = build_motion(scene, PHYSICS_OVERSAMPLE)
        loads = foot_loads(
            motion.world, motion.com, motion.rate_hz, subject.mass_kg, motion.ground_z
        )
        feet.append(draw_feet(subject.foot_length, subject.style_seed, scene.seed))
        shares.append(walking_load_shares(motion, loads, feet[-1]))
        figures.append(measure(motion, loads).as_dict() | shares[-1])
        if progress is not None:
            progress(f"subject {i + 1}/{count}: {subject.height_m:.2f} m, {subject.mass_kg:.0f} kg")
    rows = tuple(
        Row(
            ref,
            tuple(
                f[ref.figure_key] if ref.applies_to(s.traits.strike, ft.shape.arch) else math.nan
                for f, s, ft in zip(figures, subjects, feet, strict=True)
            ),
        )
        for ref in REFERENCES
    )
    return Realism(rows, subjects, seed, trait_spread(), tuple(feet), tuple(shares))


def walking_load_shares(motion: Motion, loads: FootLoads, feet: Feet) -> dict[str, float]:
    """Each plantar region's share of both feet's force-time integral while walking.

    Rendered at the motion's (physics) rate with the subject's own feet on
    the insole: the pressure in kPa (before the insole's threshold and
    curve), summed per region under each taxel (``PressureRenderer.region``).
    """
    walking = np.flatnonzero(motion.action == ACTIONS.index("walking"))
    if walking.size == 0:
        return {f"share_{name}": math.nan for name in REGION_NAMES}
    part = FootLoads(
        loads.load_n[walking],
        loads.cop_u[walking],
        loads.cop_medial[walking],
        loads.contact[walking],
        loads.total_n[walking],
    )
    renderer = PressureRenderer(motion.subject.foot_length, feet)
    kpa = renderer.kpa(part).astype(np.float64)  # (n, 2, 32, 22)
    impulse = np.array(
        [
            sum(kpa[:, foot, renderer.region[foot] == r].sum() for foot in (0, 1))
            for r in range(len(REGION_NAMES))
        ]
    )
    total = impulse.sum()
    return {
        f"share_{name}": float(v / total) for name, v in zip(REGION_NAMES, impulse, strict=True)
    }


def _fmt(value: float) -> str:
    if value == 0.0:
        return "0"
    return f"{value:.3g}" if abs(value) < 100 else f"{value:.0f}"


def _range(ref: Reference) -> str:
    if ref.low == ref.high:
        return _fmt(ref.low)
    return f"{_fmt(ref.low)} - {_fmt(ref.high)}"


def realism_markdown(result: Realism, command: str, pictures: list[tuple[str, str]]) -> str:
    """The doc: quantities against their ranges, the drawn traits, the pictures."""
    out = [
        "# How real the simulated insole is",
        "",
        f"Written by `{command}`; every figure below comes from that command.",
        "",
        f"Measured on {len(result.subjects)} drawn subjects (`draw_subjects({len(result.subjects)},"
        f" {result.seed})`), each doing a short scene of every action"
        f" ({', '.join(f'{a} x{n}' for a, n in _SCRIPT)}, a stand after each), built at"
        f" {PHYSICS_OVERSAMPLE} x 16 Hz so that forces come from resolved accelerations."
        " Forces are in body weights (BW). The range is what people show (source beside it);"
        " the simulated column gives the median over subjects and the smallest and largest"
        " subject; *inside* means every subject's value lies in the range, except for the"
        " load shares (marked *median*), which the literature gives as population means: there"
        " the median over subjects is judged, and each subject's shares are listed below.",
        "",
        "| quantity | people | source | simulated: median (min - max) | inside |",
        "|---|---|---|---|---|",
    ]
    for row in result.rows:
        ref = row.reference
        got = row.measured
        sim = f"{_fmt(float(np.median(got)))} ({_fmt(min(got))} - {_fmt(max(got))})" if got else "-"
        unit = f" {ref.unit}" if ref.unit else ""
        verdict = ("yes" if row.inside else "**no**") if got else "not drawn"
        if got and ref.judge == "median":
            verdict += " (median)"
        out.append(f"| {ref.quantity} | {_range(ref)}{unit} | {ref.source} | {sim} | {verdict} |")
    measured = result.measured_rows
    inside = sum(r.inside for r in measured)
    out += ["", f"{inside} of {len(measured)} measured figures inside their range.", ""]
    out += _subjects_table(result.subjects, result.feet, result.walking_shares)
    out += _spread_table(result.spread)
    out += _feet_table(result.spread.subjects, result.spread.seed)
    if pictures:
        out += ["## Each action, rendered", ""]
        out += [
            "Made by `scotti sim render` of a short scene per action (the first measured"
            " subject, the realistic insole, no effects): both pressure maps at four moments,"
            " the skeleton, the action and progress over time.",
            "",
        ]
        for action, rel in pictures:
            out += [f"### {action}", "", f"![{action}]({rel})", ""]
    return "\n".join(out).rstrip() + "\n"


def _subjects_table(
    subjects: tuple[Subject, ...], feet: tuple[Feet, ...], shares: tuple[dict[str, float], ...]
) -> list[str]:
    out = [
        "## The measured subjects",
        "",
        "Walking load shares (heel / midfoot / metatarsal heads / toes) for every subject;"
        " the table above judges normal arches only, since flat feet load the midfoot more"
        " and high arches less (Cavanagh & Rodgers 1987).",
        "",
        "| # | height m | mass kg | foot m | arch | walking speed m/s | cadence /min | strike"
        " | walking load shares |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for i, (s, ft, sh) in enumerate(zip(subjects, feet, shares, strict=True), start=1):
        t = s.traits
        split = " / ".join(f"{sh[f'share_{name}']:.2f}" for name in REGION_NAMES)
        out.append(
            f"| {i} | {s.height_m:.2f} | {s.mass_kg:.1f} | {s.foot_length:.3f} |"
            f" {ft.shape.arch} | {t.walking_speed_mps:.2f} | {t.cadence_spm:.0f} | {t.strike} |"
            f" {split} |"
        )
    return [*out, ""]


def _spread_table(spread: PopulationSpread) -> list[str]:
    out = [
        "## How people differ: the drawn traits",
        "",
        f"Over {spread.subjects} subjects drawn with seed {spread.seed} (`trait_spread()`): each"
        " trait's range and source, and how it came out.",
        "",
        "| trait | unit | drawn in | source | min | 5 % | mean | 95 % | max |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for t in spread.traits:
        d = t.drawn_in
        out.append(
            f"| {t.name} | {d.unit} | {_fmt(d.low)} - {_fmt(d.high)} | {d.source} |"
            f" {_fmt(t.minimum)} | {_fmt(t.p5)} | {_fmt(t.mean)} | {_fmt(t.p95)} |"
            f" {_fmt(t.maximum)} |"
        )
    shares = ", ".join(
        f"{k} {spread.strike_shares[k]:.2f} (aimed {spread.strike_shares_aimed[k]:.2f})"
        for k in spread.strike_shares
    )
    return [*out, "", f"Strike patterns drawn: {shares}.", ""]


def _feet_table(count: int, seed: int) -> list[str]:
    """Arch types, ball widths and placements over the same population as the traits."""
    feet = [
        draw_feet(s.foot_length, s.style_seed, session_seed=i)
        for i, s in enumerate(draw_subjects(count, seed))
    ]
    arches = [f.shape.arch for f in feet]
    shares = ", ".join(f"{a} {arches.count(a) / len(arches):.2f}" for a in ARCH_TYPES)
    columns = {
        "arch height (mm)": [f.shape.arch_height_mm for f in feet],
        "ball width (x foot length)": [f.shape.ball_width_ratio for f in feet],
        "placement along (mm, left foot)": [f.placement[0].along_mm for f in feet],
        "placement across (mm, left foot)": [f.placement[0].across_mm for f in feet],
        "rotation on the insole (deg, left foot)": [f.placement[0].rotation_deg for f in feet],
    }
    out = [
        "## How feet differ: shape and placement on the insole",
        "",
        f"The same {count} subjects' feet (`foot.draw_feet`, one session each). Arch types drawn:"
        f" {shares} (aimed at a quarter high, half normal, a quarter flat after the arch-index"
        " quartiles of Cavanagh & Rodgers 1987, J Biomech 20:547).",
        "",
        "| trait | min | 5 % | mean | 95 % | max |",
        "|---|---|---|---|---|---|",
    ]
    for name, raw in columns.items():
        v = np.asarray(raw, dtype=np.float64)
        p5, p95 = np.percentile(v, [5, 95])
        out.append(
            f"| {name} | {_fmt(float(v.min()))} | {_fmt(float(p5))} | {_fmt(float(v.mean()))} |"
            f" {_fmt(float(p95))} | {_fmt(float(v.max()))} |"
        )
    return [*out, ""]


def render_pictures(subject: Subject, seed: int, out_dir: Path) -> list[tuple[str, Path]]:
    """One PNG per action (``realism-<action>.png`` in ``out_dir``) via the session renderer."""
    from scotti.sim.corpus import render_scene
    from scotti.sim.render import load_span, render_png

    out_dir.mkdir(parents=True, exist_ok=True)
    made: list[tuple[str, Path]] = []
    with tempfile.TemporaryDirectory() as tmp:
        for action in ACTIONS:
            scene = Scene(
                name=f"realism-{action}",
                description=f"{action}, 12 s, the first measured subject, realistic insole",
                seed=seed,
                subject=measuring_scene(subject, seed).subject,
                script=[ScriptEntry(action=action, duration_s=12.0, stand_s=1.0)],
            )
            session = Path(tmp) / f"{action}.ses"
            render_scene(scene, session)
            png = out_dir / f"realism-{action}.png"
            render_png(load_span(session, 1.5, 8.0), png)
            made.append((action, png))
    return made
