"""Real gaitpdb walking against our simulated walking, measured as gait: docs/real-data.md.

    nice -n 19 python experiments/real_vs_sim_gait.py [--write docs/real-data.md]

Reads, with the project's own reader (``scotti.export.data.load_session``, the
daemon's pairing of feet; cache in data/real_vs_sim/cache):

- real: the eight gaitpdb walks as ``experiments/real_data.py`` imported them
  (data/realdata/<name>_01.scotti; run that script first), and the other
  insoles' walks it imports (pedar's, Moticon's: ``OTHER_REAL``);
- simulated: the three people of ``experiments/insole_transfer.py``
  (data/insole_transfer/people, our own 32 x 22 grid) and the same sessions
  rendered through gaitpdb's 8 sensors (``import-gaitpdb-8``: 100 Hz, as an
  import brings a gaitpdb file in; ``cells-gaitpdb-8``: 16 Hz), only the
  frames labelled ``walking`` (and, to compare, ``step_up``).

Per file (real) or person and label (simulated), from each foot's load (the
sum of kPa over its taxels, our count curve read backwards, so a force in
units of one taxel's area), with contact where a foot carries more than 5 %
of the body-weight proxy ``bw`` (the median of both feet's summed load):
cadence (steps/min), stance and swing time, double-support share, peak
foot load and the summed load in double support over ``bw``, the share of
a foot's stance load under its rear half (heel) and the centre of pressure
along the foot at the start and end of stance (0 heel end .. 1 toe tip),
the mean centre across the foot (0 medial .. 1 lateral) per foot, left/right
ratios, the frame-to-frame change (of a foot's load over ``bw``, and of the
cells: sum |delta| / sum), the share of zero cells inside the outline while a
foot stands, and the counts of the loaded cells (median, 95th percentile).
It trains and replays nothing.
"""

from __future__ import annotations

import argparse
import itertools
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import ROOT, ExperimentError, write_between_markers
from common import table as markdown_table

REAL: Final = ("GaCo01", "GaCo02", "JuCo01", "JuCo02", "SiCo01", "GaPt03", "JuPt01", "SiPt02")
# The other insoles' walks (experiments/real_data.py imports them too): (group, name, file
# stem). The pedar file stands for its first 2.5 s; the Moticon walks are tagged by pace.
OTHER_REAL: Final = (
    ("real pedar-x", "pedar", "pedar_example"),
    ("real Moticon", "102114 normal", "230927_102114"),
    ("real Moticon", "102137 slow", "230927_102137"),
    ("real Moticon", "102231 fast", "230927_102231"),
    ("real Moticon", "text_export", "text_export"),
)
REAL_DIR: Final = ROOT / "data" / "realdata"
SIM_DIR: Final = ROOT / "data" / "insole_transfer"
CACHE: Final = ROOT / "data" / "real_vs_sim" / "cache"
CONTACT: Final = 0.05  # a foot is on the ground above this share of the body-weight proxy
EDGE: Final = 0.2  # share of a stance at its start and end for the centre of pressure there
MIN_RUN_S: Final = 3.0  # shorter labelled runs hold no whole stride
# Below this a cell is taken as unloaded: our count curve reads any count as at least its
# 20 kPa threshold, and the simulated electronics' noise alone reaches 40 counts on a foot
# in the air (data/insole_transfer/people), a third of the cells, which would otherwise
# sum to a foot that never leaves the ground.
NOISE_COUNTS: Final = 50
BEGIN, END = "<!-- real-vs-sim:begin -->", "<!-- real-vs-sim:end -->"


@dataclass(frozen=True)
class Gait:
    """What one person's walk (or step-ups) looks like on the measures above."""

    seconds: float
    cadence: float  # steps/min, both feet
    stance_s: float
    swing_s: float
    double_support: float  # share of the time both feet are on the ground
    bw: float  # body-weight proxy: median of both feet's summed load (kPa x taxels)
    peak_bw: float  # median over stances of a foot's peak load / bw
    double_total_bw: float  # mean summed load during double support / bw
    heel_share: float  # share of a foot's stance load on its rear half
    cop_start: float  # centre of pressure along the foot, 0 heel .. 1 toe, stance start
    cop_end: float  # the same at stance end
    across_left: float  # mean centre across the foot, 0 medial .. 1 lateral, left stance
    across_right: float
    load_lr: float  # mean left load / mean right load
    stance_lr: float  # median left stance / median right stance
    load_change: float  # mean |frame-to-frame change| of a foot's load / bw
    cell_change: float  # sum |frame-to-frame change| / sum, over the cells of both feet
    zero_share: float  # share of cells inside the outline reading 0 while that foot stands
    counts_median: float  # counts of the loaded cells while a foot stands
    counts_p95: float


def loaded_kpa(counts: np.ndarray) -> np.ndarray:
    """kPa of each cell (our count curve read backwards), 0 under the noise floor."""
    from scotti.export.sensor_transfer import kpa_from_whole_counts

    return np.where(counts >= NOISE_COUNTS, kpa_from_whole_counts(counts), np.float32(0.0))


def foot_loads(kpa: np.ndarray) -> np.ndarray:
    """(N, 2): each foot's summed kPa (left columns first, as the daemon pairs them)."""
    half = kpa.shape[2] // 2
    return np.stack([kpa[:, :, :half].sum(axis=(1, 2)), kpa[:, :, half:].sum(axis=(1, 2))], 1)


def contact_runs(on: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) frames of each whole contact; contacts cut by the run's ends are dropped.

    Frames are counted as they are sampled (a contact of k frames lasts k frame
    periods): interpolating between a frame in the air and one on the ground
    would lengthen every contact by up to a frame, more for sharp edges.
    """
    edges = np.flatnonzero(np.diff(np.concatenate([[0], on.astype(np.int8), [0]])))
    out = [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]
    return [(a, b) for a, b in out if a > 0 and b < len(on)]


def central_mean(values: Sequence[float]) -> float:
    """Mean of the values between their 10th and 90th percentiles (turns, stops left out)."""
    if not values:
        return float("nan")
    v = np.asarray(values, dtype=np.float64)
    lo, hi = np.percentile(v, [10, 90])
    kept = v[(v >= lo) & (v <= hi)]
    # Two values leave nothing between their percentiles: a short walk keeps them all.
    return float((kept if kept.size else v).mean())


def runs_of(mask: np.ndarray, segment: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) of each run of True frames within one daemon segment."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    out = []
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        cuts = a + 1 + np.flatnonzero(np.diff(segment[a:b]))
        bounds = [a, *cuts.tolist(), b]
        out += list(itertools.pairwise(bounds))
    return out


def measure(counts: np.ndarray, runs: Sequence[tuple[int, int]], rate_hz: float) -> Gait:
    """The gait measures of ``counts`` (N, rows, 2 cols) over ``runs`` of its frames."""
    from scotti.models.insole import insole_mask

    runs = [(a, b) for a, b in runs if (b - a) / rate_hz >= MIN_RUN_S]
    if not runs:
        raise ExperimentError("no labelled run of 3 s or more")
    rows, cols = counts.shape[1], counts.shape[2] // 2
    along = 1.0 - (np.arange(rows) + 0.5) / rows  # 0 heel end .. 1 toe tip
    across = (np.arange(cols) + 0.5) / cols  # 0 medial .. 1 lateral, both feet
    mask = insole_mask() if (rows, cols) == insole_mask().shape else np.ones((rows, cols), bool)
    all_kpa = [loaded_kpa(counts[a:b]) for a, b in runs]
    bw = float(np.median(np.concatenate([foot_loads(k).sum(1) for k in all_kpa])))
    strides: list[float] = []
    stances: tuple[list[float], list[float]] = ([], [])
    swings: list[float] = []
    peaks: list[float] = []
    heel = [0.0, 0.0]  # rear-half load, all load, over stances
    cop_start: list[float] = []
    cop_end: list[float] = []
    across_sums = np.zeros((2, 2))
    loaded_counts: list[np.ndarray] = []
    zeros = cells = 0
    double = double_total = frames = 0.0
    load_sum = np.zeros(2)
    change = [0.0, 0.0]  # sum |delta| of foot loads, of cells
    cell_sum = 0.0
    for (a, b), kpa in zip(runs, all_kpa, strict=True):
        loads = foot_loads(kpa)
        on = loads > CONTACT * bw
        both = on.all(1)
        double += float(both.sum())
        double_total += float(loads[both].sum())
        frames += len(loads)
        load_sum += loads.sum(0)
        change[0] += float(np.abs(np.diff(loads, axis=0)).sum()) / 2  # per foot
        c = counts[a:b].astype(np.float64)
        change[1] += float(np.abs(np.diff(c, axis=0)).sum())
        cell_sum += float(c[1:].sum())
        for f in (0, 1):
            contacts = contact_runs(on[:, f])
            for (s1, e1), (s2, _) in itertools.pairwise(contacts):
                strides.append((s2 - s1) / rate_hz)
                swings.append((s2 - e1) / rate_hz)
            stances[f].extend((e - s) / rate_hz for s, e in contacts)
            for s, e in contacts:
                peaks.append(float(loads[s:e, f].max()) / bw)
                p = kpa[s:e, :, f * cols : (f + 1) * cols]
                row_load = p.sum(2)
                heel[0] += float(row_load[:, rows // 2 :].sum())
                heel[1] += float(row_load.sum())
                cop = (row_load * along).sum(1) / np.maximum(row_load.sum(1), 1e-9)
                phase = (np.arange(e - s) + 0.5) / (e - s)
                cop_start.append(float(cop[phase <= max(EDGE, phase[0])].mean()))
                cop_end.append(float(cop[phase >= min(1 - EDGE, phase[-1])].mean()))
                col_load = p.sum(1)
                across_sums[f] += (float((col_load * across).sum()), float(col_load.sum()))
                raw = counts[a + s : a + e, :, f * cols : (f + 1) * cols][:, mask]
                zeros += int((raw == 0).sum())
                cells += raw.size
                loaded_counts.append(raw[raw >= NOISE_COUNTS])
    loaded = np.concatenate(loaded_counts) if loaded_counts else np.full(1, np.nan)
    stride = central_mean(strides)
    return Gait(
        seconds=sum(b - a for a, b in runs) / rate_hz,
        cadence=120.0 / stride,
        stance_s=central_mean(stances[0] + stances[1]),
        swing_s=central_mean(swings),
        double_support=double / frames,
        bw=bw,
        peak_bw=float(np.median(peaks)) if peaks else float("nan"),
        double_total_bw=double_total / max(double, 1.0) / bw,
        heel_share=heel[0] / max(heel[1], 1e-9),
        cop_start=float(np.mean(cop_start)) if cop_start else float("nan"),
        cop_end=float(np.mean(cop_end)) if cop_end else float("nan"),
        across_left=float(across_sums[0, 0] / max(across_sums[0, 1], 1e-9)),
        across_right=float(across_sums[1, 0] / max(across_sums[1, 1], 1e-9)),
        load_lr=float(load_sum[0] / max(load_sum[1], 1e-9)),
        stance_lr=central_mean(stances[0]) / central_mean(stances[1]),
        load_change=change[0] / max(frames, 1.0) / bw,
        cell_change=change[1] / max(cell_sum, 1e-9),
        zero_share=zeros / max(cells, 1),
        counts_median=float(np.median(loaded)),
        counts_p95=float(np.percentile(loaded, 95)),
    )


# --- which files ---------------------------------------------------------------


def _rendered(kind: str, subject: str) -> Path:
    """The current rendering of ``subject`` through gaitpdb's layout (insole_transfer's key)."""
    import insole_transfer

    (entry,) = [s for s in insole_transfer.sensors() if s.name == kind]
    assert entry.sensor is not None
    return insole_transfer.render_path(SIM_DIR / "people" / f"{subject}.ses", entry.sensor, kind)


def sources() -> list[tuple[str, str, Path, str | None]]:
    """(group, name, session file, label to keep or None for the whole file)."""
    out: list[tuple[str, str, Path, str | None]] = [
        ("real gaitpdb", name, REAL_DIR / f"{name}_01.scotti", None) for name in REAL
    ]
    out += [(group, name, REAL_DIR / f"{stem}.scotti", None) for group, name, stem in OTHER_REAL]
    people = sorted((SIM_DIR / "people").glob("subject-*.ses"))
    for label in ("walking", "step_up"):
        for kind in ("import-gaitpdb-8", "cells-gaitpdb-8", "ours"):
            if label == "step_up" and kind == "cells-gaitpdb-8":
                continue  # the 100 Hz import stands for the layout here
            for p in people:
                path = p if kind == "ours" else _rendered(kind, p.stem)
                out.append((f"sim {label}, {kind}", p.stem.removeprefix("subject-"), path, label))
    missing = [str(p) for _, _, p, _ in out if not p.is_file()]
    if missing:
        raise ExperimentError(
            f"{missing[0]}: missing (run experiments/real_data.py, experiments/insole_transfer.py)"
        )
    return out


def gait_of(path: Path, label: str | None) -> Gait:
    from scotti.export.data import load_session
    from scotti.models.contract import ACTIONS, FRAME_RATE_HZ

    s = load_session(path, CACHE)
    keep = s.frame_ok.copy()
    if label is not None:
        keep &= s.action == ACTIONS.index(label)
    return measure(s.frames, runs_of(keep, s.segment), float(FRAME_RATE_HZ))


# --- where the simulated feet are when their insoles read a load ------------------


@dataclass(frozen=True)
class Kinematic:
    """A simulated person's walking: the share of frames each foot is loaded or down."""

    loaded: float  # foot load above CONTACT x bw (mean of both feet)
    down: float  # lowest foot keypoint (heel, toes) within CONTACT_FULL_M of the floor
    near: float  # ... within CONTACT_NONE_M (where sim/loads.py's contact ramp ends)
    both_loaded: float
    both_down: float


def kinematic_of(path: Path, label: str) -> Kinematic:
    """The labelled keypoints beside the insole's loads (flat floor: walking only)."""
    from scotti.export.data import load_session
    from scotti.models.contract import ACTIONS, KP
    from scotti.sim.loads import CONTACT_FULL_M, CONTACT_NONE_M

    s = load_session(path, CACHE)
    keep = s.frame_ok & (s.action == ACTIONS.index(label))
    loads = foot_loads(loaded_kpa(s.frames[keep]))
    on = loads > CONTACT * np.median(loads.sum(1))
    kp = s.keypoints[keep]
    parts = [
        [KP[f"{side}_{p}"] for p in ("heel", "big_toe", "small_toe")] for side in ("left", "right")
    ]
    low = np.stack([kp[:, idx, 2].min(1) for idx in parts], 1)  # (N, 2) metres above z = 0
    down, near = low <= CONTACT_FULL_M, low <= CONTACT_NONE_M
    return Kinematic(
        loaded=float(on.mean()),
        down=float(down.mean()),
        near=float(near.mean()),
        both_loaded=float(on.all(1).mean()),
        both_down=float(down.all(1).mean()),
    )


def kinematic_table(people: Sequence[Path]) -> list[str]:
    from scotti.sim.loads import CONTACT_FULL_M, CONTACT_NONE_M

    full, none = f"{CONTACT_FULL_M * 1000:g} mm", f"{CONTACT_NONE_M * 1000:g} mm"
    header = [
        "sim walking, ours",
        "foot loaded %",
        f"foot within {full} %",
        f"foot within {none} %",
        "both loaded %",
        f"both within {full} %",
    ]
    rows = []
    for p in people:
        k = kinematic_of(p, "walking")
        values = (k.loaded, k.down, k.near, k.both_loaded, k.both_down)
        rows.append([p.stem.removeprefix("subject-"), *[f"{100 * v:.0f}" for v in values]])
    return markdown_table(header, rows, "lrrrrr")


# --- the table ----------------------------------------------------------------

COLUMNS: Final = (
    ("s", "seconds", 0, 1.0),
    ("cadence /min", "cadence", 0, 1.0),
    ("stance s", "stance_s", 2, 1.0),
    ("swing s", "swing_s", 2, 1.0),
    ("double support %", "double_support", 0, 100.0),
    ("peak / bw", "peak_bw", 2, 1.0),
    ("double-support sum / bw", "double_total_bw", 2, 1.0),
    ("heel share %", "heel_share", 0, 100.0),
    ("CoP start", "cop_start", 2, 1.0),
    ("CoP end", "cop_end", 2, 1.0),
    ("across L", "across_left", 2, 1.0),
    ("across R", "across_right", 2, 1.0),
    ("load L/R", "load_lr", 2, 1.0),
    ("stance L/R", "stance_lr", 2, 1.0),
    ("load change / bw", "load_change", 3, 1.0),
    ("cell change", "cell_change", 2, 1.0),
    ("zero %", "zero_share", 0, 100.0),
    ("counts median", "counts_median", 0, 1.0),
    ("counts p95", "counts_p95", 0, 1.0),
    ("bw (kPa x taxels)", "bw", 0, 1.0),
)


def row_of(group: str, name: str, gait: Gait) -> list[str]:
    cells = [group, name]
    for _, attr, digits, scale in COLUMNS:
        value = getattr(gait, attr) * scale
        cells.append("-" if not np.isfinite(value) else f"{value:.{digits}f}")
    return cells


def render(rows: list[tuple[str, str, Gait]], command: str, kinematic: Sequence[str]) -> str:
    """Two markdown tables (timing and load; where and how much), one row per file or person,
    then the simulated feet's keypoints beside their loads."""
    lines = [f"Written by `{command}`.", ""]
    half = 10
    for cols in (COLUMNS[:half], COLUMNS[half:]):
        header = ["what", "file / person", *[c[0] for c in cols]]
        body = []
        for group, name, gait in rows:
            full = row_of(group, name, gait)
            body.append(full[:2] + [full[2 + COLUMNS.index(c)] for c in cols])
        lines += markdown_table(header, body, "ll" + "r" * len(cols))
        lines.append("")
    return "\n".join([*lines, *kinematic, ""])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python experiments/real_vs_sim_gait.py",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--write", type=Path, help="replace the marked section of this doc")
    args = parser.parse_args(argv)
    command = "python experiments/real_vs_sim_gait.py " + " ".join(
        argv if argv is not None else sys.argv[1:]
    )
    try:
        rows = []
        for group, name, path, label in sources():
            rows.append((group, name, gait_of(path, label)))
            print(" | ".join(row_of(group, name, rows[-1][2])), flush=True)
        people = sorted((SIM_DIR / "people").glob("subject-*.ses"))
        text = render(rows, command.strip(), kinematic_table(people))
        print(text)
        if args.write:
            write_between_markers(args.write, text, BEGIN, END)
    except ExperimentError as exc:
        print(f"real_vs_sim_gait: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
