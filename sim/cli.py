"""``scotti sim``: scenes into session files, corpora, pictures and the speed benchmark.

    scotti sim SCENE -o FILE [--seed N] [--force]
    scotti sim corpus -o DIR --subjects N [--seed N] [--minutes-per-action M]
                      [--effects realistic|none] [--force]
    scotti sim render FILE -o OUT.png [--start S] [--duration D] [--gif OUT.gif] [--force]
    scotti sim bench [--minutes M] [--effects realistic|none]
    scotti sim realism [-o sim/REALISM.md] [--subjects N] [--seed N] [--no-pictures]

The first word picks the form: ``corpus``, ``render``, ``bench`` and ``realism`` are
sub-verbs; anything else is a scene file (a scene file literally named
``corpus`` can be given as ``./corpus``).

An output that exists is refused unless ``--force`` (a corpus: a directory
that holds session files); ``realism`` rewrites its document in place, as the
commands that remake the repository's documents do.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Final

from scotti.firmware_protocol.overwrite import FORCE_HELP, REFUSED, refuse_existing

SUB_VERBS: Final = ("corpus", "render", "bench", "realism")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.description = __doc__
    parser.usage = "scotti sim {SCENE -o FILE | corpus ... | render ... | bench ...} [-h]"
    parser.add_argument(
        "words",
        nargs=argparse.REMAINDER,
        metavar="SCENE|corpus|render|bench ...",
        help="a scene file and its options, or a sub-verb and its options",
    )


def _scene_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="scotti sim", description="render a scene to a session file")
    p.add_argument("scene", type=Path, help="scene TOML file")
    p.add_argument(
        "-o", "--output", type=Path, required=True, help=f"session file to write ({REFUSED})"
    )
    p.add_argument("--seed", type=int, default=None, help="override the scene's seed")
    p.add_argument("--force", action="store_true", help=FORCE_HELP)
    return p


def _corpus_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="scotti sim corpus",
        description="N drawn subjects, each a lab session: every action in sets, standing "
        "between, walks and turns between spots",
    )
    p.add_argument(
        "-o",
        "--output",
        type=Path,
        required=True,
        help="directory to fill (one that holds session files is refused, unless --force)",
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="write into a directory that holds session files (same names are replaced; "
        "with --first-subject: extend a corpus in place, its manifest replaced)",
    )
    p.add_argument("--subjects", type=int, required=True, help="how many subjects to draw")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--first-subject",
        type=int,
        default=0,
        metavar="INDEX",
        help="start at this subject of the seed's population (extend a corpus with new people)",
    )
    p.add_argument(
        "--minutes-per-action", type=float, default=4.0, help="at least this much of each action"
    )
    p.add_argument(
        "--effects",
        choices=("realistic", "none", "mixed", "wide"),
        default="realistic",
        help="transport and sensor effects: a fresh realistic draw per subject, none, "
        "mixed (a third of the subjects clean), or wide (the realistic draw with three "
        "effects drawn over the whole range a scene accepts; sim/effects/wide.py)",
    )
    p.add_argument(
        "--insoles",
        choices=("typical", "wide"),
        default="typical",
        help="each subject's insole drawn near the nominal curve, or over the wide range of "
        "insoles users bring (sim/insole.py draw_insole)",
    )
    p.add_argument(
        "--paces",
        choices=("typical", "wide"),
        default="typical",
        help="walking speeds of the typical adult population (1.05-1.65 m/s), or drawn "
        "uniformly over 0.5-1.65 m/s so that slow walkers are met too (sim/traits.py)",
    )
    p.add_argument(
        "--bodies",
        choices=("typical", "wide"),
        default="typical",
        help="adults of 1.50-1.95 m, or height, mass and foot length drawn over what a "
        "scene accepts (1.2-2.2 m, 30-200 kg, feet 0.15-0.35 m; sim/corpus.py wide_body)",
    )
    p.add_argument(
        "--gaits",
        choices=("typical", "wide"),
        default="typical",
        help="the typical push-off at toe-off and touch-down pitch, or both drawn over what a "
        "scene accepts (push_off 0.15-1: shuffling walkers; sim/corpus.py wide_gait)",
    )
    return p


def _render_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="scotti sim render", description="draw a session")
    p.add_argument("session", type=Path, help="session file with labels")
    p.add_argument("-o", "--output", type=Path, required=True, help=f"PNG to write ({REFUSED})")
    p.add_argument("--start", type=float, default=0.0, help="seconds from the first frame")
    p.add_argument(
        "--duration", type=float, default=None, help="seconds to draw (default: to the end)"
    )
    p.add_argument("--gif", type=Path, default=None, help=f"also write an animated GIF ({REFUSED})")
    p.add_argument("--force", action="store_true", help=FORCE_HELP)
    return p


def _bench_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="scotti sim bench", description="speed against real time")
    p.add_argument("--minutes", type=float, default=10.0, help="minutes to simulate")
    p.add_argument("--effects", choices=("realistic", "none"), default="none")
    return p


def _realism_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="scotti sim realism", description="the simulator against published ranges"
    )
    p.add_argument(
        "-o",
        "--output",
        type=Path,
        default=Path("sim/REALISM.md"),
        help="the document to (re)write in place, pictures in img/ beside it",
    )
    p.add_argument("--subjects", type=int, default=8, help="drawn subjects to measure")
    p.add_argument("--seed", type=int, default=7, help="seed of the drawn subjects")
    p.add_argument(
        "--no-pictures", action="store_true", help="skip the per-action renders (no matplotlib)"
    )
    return p


def run(args: argparse.Namespace) -> int:
    words: list[str] = list(args.words)
    if not words:
        print("scotti sim: give a scene file or one of corpus, render, bench (-h)", file=sys.stderr)
        return 2
    try:
        return _dispatch(words)
    except Exception as exc:  # user mistakes from any room, as one line
        from scotti.firmware_protocol.errors import ProtocolError
        from scotti.sim import SimError

        if isinstance(exc, SimError | ProtocolError | OSError):
            print(f"scotti sim: {exc}", file=sys.stderr)
            return 2
        raise


def _dispatch(words: list[str]) -> int:
    verb = words[0]
    if verb == "corpus":
        return _corpus(_corpus_parser().parse_args(words[1:]))
    if verb == "render":
        return _render(_render_parser().parse_args(words[1:]))
    if verb == "bench":
        return _bench(_bench_parser().parse_args(words[1:]))
    if verb == "realism":
        return _realism(_realism_parser().parse_args(words[1:]))
    return _scene(_scene_parser().parse_args(words))


def _scene(a: argparse.Namespace) -> int:
    from scotti.sim.corpus import render_scene
    from scotti.sim.scene import load_scene

    refuse_existing([a.output], force=a.force)
    scene = load_scene(a.scene)
    report = render_scene(scene, a.output, seed=a.seed)
    print(
        f"{a.output}: {report.duration_s:.1f} s, {report.frames} frames, "
        f"{report.packet_records} packet records, {report.bytes_written} bytes on the line"
        + (f", effects: {', '.join(report.effects)}" if report.effects else "")
    )
    return 0


def _corpus(a: argparse.Namespace) -> int:
    from scotti.sim import SimError
    from scotti.sim.corpus import MANIFEST, write_corpus

    if a.subjects < 1 or a.first_subject < 0 or not 0 < a.minutes_per_action <= 60:
        msg = "--subjects must be >= 1, --first-subject >= 0 and --minutes-per-action in (0, 60]"
        raise SimError(msg)
    held = session_files_in(a.output)
    if held and not a.force:
        files = f"{held} session file{'s' if held > 1 else ''}"
        msg = f"{a.output} holds {files}; --force writes into it anyway"
        raise SimError(msg)
    manifest = write_corpus(
        a.output,
        subjects=a.subjects,
        first=a.first_subject,
        seed=a.seed,
        minutes_per_action=a.minutes_per_action,
        effects=a.effects,
        insoles=a.insoles,
        paces=a.paces,
        bodies=a.bodies,
        gaits=a.gaits,
        progress=lambda line: print(line, flush=True),  # a line per subject, as it is done
    )
    total = manifest["total_duration_s"]
    print(f"{a.output / MANIFEST}: {a.subjects} subjects, {total / 60:.1f} min in all")
    return 0


def _render(a: argparse.Namespace) -> int:
    from scotti.sim.render import load_span, render_gif, render_png

    if (a.duration is not None and a.duration <= 0) or a.start < 0:
        from scotti.sim import SimError

        msg = "--start must be >= 0 and --duration > 0"
        raise SimError(msg)
    refuse_existing([a.output] + ([a.gif] if a.gif is not None else []), force=a.force)
    span = load_span(a.session, a.start, a.duration)
    print(render_png(span, a.output))
    if a.gif is not None:
        print(render_gif(span, a.gif))
    return 0


def _bench(a: argparse.Namespace) -> int:
    from scotti.sim.bench import run_bench

    if not 0 < a.minutes <= 120:
        from scotti.sim import SimError

        msg = "--minutes must be in (0, 120]"
        raise SimError(msg)
    result = run_bench(a.minutes, effects=a.effects == "realistic")
    for line in result.lines():
        print(line)
    return 0


def _realism(a: argparse.Namespace) -> int:
    """Measure, write the doc (and pictures beside it); exit 1 if a figure is out of range."""
    from scotti.sim import SimError
    from scotti.sim.realism import measure_population, realism_markdown, render_pictures

    if not 1 <= a.subjects <= 100:
        msg = "--subjects must be in 1..100"
        raise SimError(msg)
    result = measure_population(a.subjects, a.seed, progress=lambda line: print(line, flush=True))
    pictures: list[tuple[str, str]] = []
    if not a.no_pictures:
        img = a.output.parent / "img"
        for action, png in render_pictures(result.subjects[0], a.seed, img):
            pictures.append((action, str(png.relative_to(a.output.parent))))
    words = ["scotti sim realism", f"--subjects {a.subjects}", f"--seed {a.seed}"]
    if a.output != Path("sim/REALISM.md"):
        words.append(f"-o {a.output}")
    if a.no_pictures:
        words.append("--no-pictures")
    a.output.write_text(realism_markdown(result, " ".join(words), pictures))
    measured = result.measured_rows
    outside = [r.reference.quantity for r in measured if not r.inside]
    print(f"{a.output}: {len(measured) - len(outside)} of {len(measured)} figures inside")
    for quantity in outside:
        print(f"  outside its range: {quantity}")
    return 0 if not outside else 1


def session_files_in(folder: Path) -> int:
    """How many session files ``folder`` holds (0 when it is not a directory)."""
    from scotti.firmware_protocol.errors import SessionError
    from scotti.firmware_protocol.session import find_session_files

    if not folder.is_dir():
        return 0
    try:
        return len(find_session_files([folder]))
    except SessionError:  # none found is an error there: a directory of other files
        return 0
