"""Real walks played slower and faster: how the model's walking depends on pace (docs/real-data.md).

    python experiments/real_tempo.py --model models/scotti-default.onnx \\
        [--model OTHER.onnx] [--tempo 0.65 0.8 1 1.25] [--write docs/real-data.md]

The real recordings hold few slow walkers (docs/real-data.md: four walks under
95 steps a minute, each a different person and insole), so cadence and person
cannot be told apart there. Here each of gaitpdb's eight walks
(``../shared/realdata/physionet-gaitpdb``, 100 Hz, its first column the time in
seconds) is written again with its clock divided by a tempo (0.8: every
second of the recording now lasts 1.25 s, the walk 20 % slower), imported by
``scotti import --format gaitpdb`` as any gaitpdb file, and replayed through
the daemon's path with each model (experiments/real_data.py's scoring):
the same people, feet and insole at other cadences.

What it is not: a slow walker. Played slower, a walk keeps its stance share
and its loads' shapes and only changes speed; a person walking slowly stands
longer in each cycle (sim/actions/gait.py's ``stance_share``) and presses
otherwise. So the table says how much the model's reading hangs on the
frames' tempo alone, on real feet; the real slow walks are in the table above
it. Cadence is measured on the imported file (real_data's ``steps /min``).
Work files go to data/real_tempo (a tempo's copy is remade only when missing).
"""

from __future__ import annotations

import argparse
import gzip
import sys
import time
from pathlib import Path
from typing import Any, Final

sys.path.insert(0, str(Path(__file__).resolve().parent))
import real_data
from common import ROOT, ExperimentError, run, scotti_command, write_between_markers
from common import table as markdown_table

WORK: Final = ROOT / "data" / "real_tempo"
TEMPI: Final = (0.65, 0.8, 1.0, 1.25)
BEGIN, END = "<!-- real-tempo:begin -->", "<!-- real-tempo:end -->"
GAITPDB: Final = tuple(r for r in real_data.RECORDINGS if r.sensor.startswith("gaitpdb"))


def retimed_text(text: str, tempo: float) -> str:
    """A gaitpdb text file with its time column (the first) divided by ``tempo``."""
    if tempo <= 0:
        raise ExperimentError(f"a tempo must be above 0, got {tempo}")
    out = []
    for line in text.splitlines():
        time_s, sep, rest = line.partition("\t")
        if not sep:  # a line without columns (a blank end) stays as it is
            out.append(line)
            continue
        try:
            seconds = float(time_s)
        except ValueError as exc:
            raise ExperimentError(f"not a gaitpdb line (time {time_s!r}): {line[:60]!r}") from exc
        out.append(f"{seconds / tempo:.5f}\t{rest}")
    return "\n".join(out) + "\n"


def retimed_session(rec: real_data.Recording, tempo: float, realdata: Path, work: Path) -> Path:
    """The recording at ``tempo``, imported (kept in ``work``)."""
    out = work / f"{rec.name}.x{tempo:g}.scotti"
    if out.is_file():
        return out
    work.mkdir(parents=True, exist_ok=True)
    raw = (realdata / rec.path).read_bytes()
    text = (gzip.decompress(raw) if rec.path.endswith(".gz") else raw).decode("ascii")
    source = work / f"{rec.name}.x{tempo:g}.txt"
    source.write_text(retimed_text(text, tempo))
    part = work / f".{out.name}.part"
    cmd = scotti_command("import", source, "--format", "gaitpdb", "-o", part, "--force")
    run(cmd, work / "import.log")
    part.replace(out)
    source.unlink()
    return out


def measure(
    models: list[Path], tempi: list[float], realdata: Path, work: Path
) -> list[dict[str, Any]]:
    """One row per recording, tempo and model: cadence, walking, unfamiliar."""
    rows = []
    for rec in GAITPDB:
        for tempo in tempi:
            session = retimed_session(rec, tempo, realdata, work)
            cadence = real_data.cadence_of(session)
            for row in real_data.score_file(rec, session, models):
                rows.append({**row, "tempo": tempo, "cadence": cadence})
            print(f"real_tempo: {rec.name} x{tempo:g} done", file=sys.stderr, flush=True)
    return rows


def band_of(cadence: float | None) -> str:
    """The pace band a walk falls in (steps a minute)."""
    if cadence is None:
        return "-"
    edges = (60, 75, 90, 105, 120)
    low = max((e for e in edges if cadence >= e), default=None)
    if low is None:
        return f"under {edges[0]}"
    high = next((e for e in edges if e > low), None)
    return f"{low}-{high}" if high else f"{low} and more"


def render(rows: list[dict[str, Any]], tempi: list[float], command: str) -> str:
    models = list(dict.fromkeys(r["model"] for r in rows))
    lines = [f"Written by `{command}` on {time.strftime('%Y-%m-%d')}.", ""]
    header = ["file", "model"] + [f"x{t:g}" for t in tempi]
    body = []
    for name in dict.fromkeys(r["file"] for r in rows):
        for model in models:
            mine = {r["tempo"]: r for r in rows if r["file"] == name and r["model"] == model}
            cells = []
            for t in tempi:
                r = mine.get(t)
                cells.append("-" if r is None else f"{_cad(r)}: {real_data._pct(r['walking'])}")
            body.append([name, model, *cells])
    lines += ["Per walk: steps a minute at that tempo, and the share read as walking.", ""]
    lines += markdown_table(header, body, "ll" + "r" * len(tempi))
    lines += ["", "Pooled by pace (every walk at every tempo, windows weighted):", ""]
    bands = sorted({band_of(r["cadence"]) for r in rows}, key=_band_key)
    pooled = []
    for band in bands:
        mine = [r for r in rows if band_of(r["cadence"]) == band]
        walks = len({(r["file"], r["tempo"]) for r in mine})
        cells = []
        for model in models:
            of = [r for r in mine if r["model"] == model]
            walking = real_data._pooled(of, "walking", "walking_windows")
            unfamiliar = real_data._pooled(of, "unfamiliar", "predictions")
            cells.append(f"{walking} ({unfamiliar})")
        pooled.append([band, str(walks), *cells])
    header = ["steps /min", "walks", *[f"{m}: walking (unfamiliar)" for m in models]]
    lines += markdown_table(header, pooled, "lr" + "r" * len(models))
    return "\n".join(lines) + "\n"


def _cad(row: dict[str, Any]) -> str:
    return "-" if row["cadence"] is None else f"{row['cadence']:.0f}"


def _band_key(band: str) -> float:
    head = band.split("-")[0].split(" ")[0]
    return -1.0 if head == "under" else float(head) if head != "-" else float("inf")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python experiments/real_tempo.py",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--model", type=Path, action="append", help="an ONNX graph (repeatable)")
    parser.add_argument("--tempo", type=float, nargs="+", default=list(TEMPI))
    parser.add_argument("--realdata", type=Path, default=real_data.REALDATA)
    parser.add_argument("--work", type=Path, default=WORK)
    parser.add_argument("--write", type=Path, help="replace the marked section of this doc")
    args = parser.parse_args(argv)
    models = args.model or [ROOT / "models" / "scotti-default.onnx"]
    try:
        if not args.realdata.is_dir():
            raise ExperimentError(f"{args.realdata}: no such folder (see its README)")
        if any(t <= 0 for t in args.tempo):
            raise ExperimentError("every --tempo must be above 0")
        for model in models:
            if not model.is_file():
                raise ExperimentError(f"{model}: no such model")
        rows = measure(models, args.tempo, args.realdata, args.work)
    except ExperimentError as exc:
        print(f"real_tempo: {exc}", file=sys.stderr)
        return 2
    shown = " ".join(f"--model {real_data.label(m)}.onnx" for m in models)
    tempi = " ".join(f"{t:g}" for t in args.tempo)
    command = f"python experiments/real_tempo.py {shown} --tempo {tempi}"
    if args.write:
        command += f" --write {args.write}"
    text = render(rows, args.tempo, command)
    print(text)
    if args.write:
        write_between_markers(args.write, text, BEGIN, END)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
