"""Simulated walking measured as gait, as experiments/real_vs_sim_gait.py measures it.

    nice -n 19 python experiments/sim_walking_gait.py [--people 3] [--steps 24] \
        [--trait push_off=0.3 --trait walking_speed_mps=0.8 ...]

Renders a short clean walking scene (our own 32 x 22 grid, the ``realistic``
insole, no transport effects) for each of the people of
``experiments/insole_transfer.py`` (corpus seed 7, subjects 200, 201, ...;
same bodies and styles, not their corpus sessions), decodes it with the
project's reader (``scotti.export.data.load_session``) and prints the timing
and load columns of real_vs_sim_gait's table plus the stance share of the stride.
``--trait NAME=VALUE`` gives every person that trait (sim/traits.py; a
value outside the range a scene accepts is refused), e.g. a shuffler's
``push_off`` at a slow pace, to put beside the real walks of docs/real-data.md.
Writes nothing outside a temporary folder; a few seconds per person.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Final

sys.path.insert(0, str(Path(__file__).resolve().parent))
import real_vs_sim_gait as gait
from common import table as markdown_table

if TYPE_CHECKING:
    from scotti.sim.scene import Scene

CORPUS_SEED: Final = 7  # experiments/insole_transfer.py's people
FIRST_SUBJECT: Final = 200


@dataclass(frozen=True)
class Phases:
    """One walk's gait phases, from its decoded pressure frames."""

    gait: gait.Gait
    stride_s: float

    @property
    def stance_share(self) -> float:
        """Stance over the stride (the gait cycle)."""
        return self.gait.stance_s / self.stride_s

    @property
    def swing_share(self) -> float:
        """Swing over the stride."""
        return self.gait.swing_s / self.stride_s


def person_scene(
    subject_index: int, steps: int, seed: int = 1, traits: dict[str, float] | None = None
) -> Scene:
    """``steps`` walking steps of corpus person ``subject_index``, standing a second before,
    with ``traits`` given (the rest drawn from the person's style seed)."""
    from scotti.sim.scene import Scene, ScriptEntry, SubjectModel
    from scotti.sim.subjects import draw_subjects

    subject = draw_subjects(subject_index + 1, CORPUS_SEED)[subject_index]
    return Scene(
        name=f"walking-{subject_index}",
        seed=seed,
        subject=SubjectModel.of(subject).model_copy(update=traits or {}),
        script=[ScriptEntry(action="walking", reps=steps, stand_s=1.0)],
    )


def walking_phases(scene: Scene, workdir: Path, trim_s: float = 0.0) -> Phases:
    """Render ``scene``, decode it and measure its walking frames.

    ``trim_s``: leave out this much of each walking run's start and end (the
    first and last steps, gait initiation and termination, stand longer on
    both feet than the steady strides between); 0 measures the whole run, as
    real_vs_sim_gait.py does.
    """
    from scotti.export.data import load_session
    from scotti.models.contract import ACTIONS, FRAME_RATE_HZ
    from scotti.sim.corpus import render_scene

    path = workdir / f"{scene.name}.ses"
    render_scene(scene, path)
    s = load_session(path)
    keep = s.frame_ok & (s.action == ACTIONS.index("walking"))
    trim = round(trim_s * FRAME_RATE_HZ)
    runs = [(a + trim, b - trim) for a, b in gait.runs_of(keep, s.segment) if b - a > 2 * trim]
    g = gait.measure(s.frames, runs, float(FRAME_RATE_HZ))
    return Phases(g, 120.0 / g.cadence)


def parse_traits(items: list[str]) -> dict[str, float]:
    """``NAME=VALUE`` items as given traits, each a known trait within the schema's range."""
    from scotti.sim.traits import TRAIT_RANGES

    traits: dict[str, float] = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or name not in TRAIT_RANGES:
            msg = f"--trait {item!r}: want NAME=VALUE with NAME one of {', '.join(TRAIT_RANGES)}"
            raise ValueError(msg)
        r = TRAIT_RANGES[name]
        try:
            number = float(value)
        except ValueError:
            number = float("nan")
        if not r.low <= number <= r.high:
            msg = f"--trait {item!r}: {name} takes {r.low:g}..{r.high:g} {r.unit}".rstrip()
            raise ValueError(msg)
        traits[name] = number
    return traits


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python experiments/sim_walking_gait.py",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--people", type=int, default=3)
    parser.add_argument("--steps", type=int, default=24, help="walking steps per person")
    parser.add_argument(
        "--trim-s", type=float, default=0.0, help="leave out this much of each walk's ends"
    )
    parser.add_argument(
        "--trait",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="give every person this trait (repeatable), e.g. push_off=0.3",
    )
    args = parser.parse_args(argv)
    try:
        traits = parse_traits(args.trait)
    except ValueError as e:
        parser.error(str(e))
    columns = gait.COLUMNS[:10]  # real_vs_sim_gait's timing-and-load table
    header = ["person", *[c[0] for c in columns], "stance % of stride"]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(FIRST_SUBJECT, FIRST_SUBJECT + args.people):
            p = walking_phases(person_scene(i, args.steps, traits=traits), Path(tmp), args.trim_s)
            cells = gait.row_of("", str(i), p.gait)[1:]
            rows.append([*cells[: 1 + len(columns)], f"{100 * p.stance_share:.0f}"])
            print(" | ".join(rows[-1]), flush=True)
    print("\n".join(markdown_table(header, rows, "l" + "r" * (len(header) - 1))))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
