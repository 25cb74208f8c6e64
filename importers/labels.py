"""Action labels (a segment file, or one action for the whole file) and progress.

A segment file is CSV, ``start,end,action`` per line (a header line is
optional): times in seconds from the first pressure frame (``time =
"relative"``, the default) or on the pressure file's own clock
(``"absolute"``, in ``time_unit``); actions by name (models/contract.py
ACTIONS). A frame at time t belongs to the segment with start <= t < end;
frames in no segment have no action (``NO_ACTION``: left out of the action
and progress losses).

With keypoints, the segments' actions follow the labelling convention
(models/contract.py), the same as the simulator's: a segment of a repeated
action keeps at most ``SET_EDGE_REST_S`` of still standing before its first
movement and after its last, and the stillness beyond is ``standing``
(models/set_edges.py); a pause between repetitions inside the segment stays
the segment's action, progress ~0, for ``SET_EDGE_REST_S``, and standing
straight-legged beyond that is ``standing``, and a squat or lunge segment
(``PAUSING_ACTIONS``) that ends before a second of still standing after its
last movement takes the standing after it up to that second, as a pause would.
Where the keypoints do not show it (none, or masked), the segment file's action
stands.

Progress comes from the keypoints by the paper's indicators, the stepping
actions cut where a foot lands (models/progress.py ``run_progress``, as the
simulator labels), one run of one action at a time, never across a gap.
Where the indicator cannot be computed (its keypoints are masked, or the
action has none) progress stays NaN: missing, not invented.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path
from typing import Final, NamedTuple

import numpy as np
from scotti.importers.config import TIME_UNITS, LabelsConfig
from scotti.importers.errors import InputError
from scotti.models.contract import ACTIONS, FRAME_RATE_HZ, NO_ACTION
from scotti.models.errors import ModelInputError
from scotti.models.progress import progress_indicator, run_progress
from scotti.models.set_edges import set_edges

# Actions that are states, not exercises: no repetitions, so no progress.
NO_PROGRESS: Final = frozenset({"standing"})
_EDGE_S: Final = 1.0 / 32.0  # half a frame: how far a segment may reach past the recording


@dataclass(frozen=True)
class Segment:
    start_s: float  # seconds on the pressure clock
    end_s: float
    action: int
    line: int


def read_segments(path: Path, cfg: LabelsConfig, t_first: float, t_last: float) -> list[Segment]:
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(path, f"cannot read ({exc.__class__.__name__})") from None
    rows = list(csv.reader(text.splitlines()))
    segments: list[Segment] = []
    scale = TIME_UNITS[cfg.time_unit]
    origin = t_first if cfg.time == "relative" else 0.0
    for number, row in enumerate(rows, start=1):
        cells = [c.strip() for c in row]
        if not any(cells):
            continue
        if number == 1 and cells[:2] == ["start", "end"]:
            continue
        if len(cells) != 3:
            raise InputError(
                path, f"{len(cells)} columns, expected 3 (start,end,action)", line=number
            )
        times = []
        for col in (0, 1):
            try:
                value = float(cells[col])
            except ValueError:
                raise InputError(
                    path, f"{cells[col]!r} is not a number", line=number, column=col + 1
                ) from None
            if not np.isfinite(value):
                raise InputError(path, "time is not a number", line=number, column=col + 1)
            times.append(origin + value * scale)
        start, end = times
        if cells[2] not in ACTIONS:
            problem = f"unknown action {cells[2]!r} (one of {', '.join(ACTIONS)})"
            raise InputError(path, problem, line=number, column=3)
        if end <= start:
            raise InputError(path, "end is not after start", line=number, column=2)
        if start < t_first - _EDGE_S or end > t_last + _EDGE_S:
            shown = (start - origin, end - origin)
            problem = f"segment {shown[0]:g}..{shown[1]:g} lies outside the recording "
            problem += f"({t_first - origin:g}..{t_last - origin:g})"
            raise InputError(path, problem, line=number, column=1 if start < t_first else 2)
        if segments and start < segments[-1].end_s:
            problem = f"overlaps the segment on line {segments[-1].line} (or comes before it)"
            raise InputError(path, problem, line=number, column=1)
        segments.append(Segment(start, end, ACTIONS.index(cells[2]), number))
    if not segments:
        raise InputError(path, "no segments")
    return segments


def frame_actions(times: np.ndarray, segments: list[Segment]) -> np.ndarray:
    """(M,) int64 action index per frame time, NO_ACTION outside every segment."""
    action = np.full(times.size, NO_ACTION, dtype=np.int64)
    for s in segments:
        action[(times >= s.start_s) & (times < s.end_s)] = s.action
    return action


class FrameLabels(NamedTuple):
    action: np.ndarray  # (M,) int64, NO_ACTION where none
    progress: np.ndarray  # (M,) float32, NaN where missing
    repetition: np.ndarray  # (M,) int32, -1 where none


def frame_labels(keypoints: np.ndarray, action: np.ndarray, segment: np.ndarray) -> FrameLabels:
    """The segment file's ``action`` (M,) held to the labelling convention where the
    keypoints (M, 19, 3, pose frame) show it, and its progress; ``segment`` (M,) the
    timeline's gap-free stretches. Frames come at the contract's rate."""
    held = set_edges(keypoints, action, FRAME_RATE_HZ, segment)
    progress, repetition = frame_progress(keypoints, held, segment)
    return FrameLabels(held, progress, repetition)


def frame_progress(
    keypoints: np.ndarray, action: np.ndarray, segment: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Progress (M,) float32 (NaN: missing) and repetition (M,) int32 (-1: none)."""
    n = action.size
    progress = np.full(n, np.nan, dtype=np.float32)
    repetition = np.full(n, -1, dtype=np.int32)
    change = np.r_[True, (action[1:] != action[:-1]) | (segment[1:] != segment[:-1])]
    starts = np.flatnonzero(change)
    ends = np.r_[starts[1:], n]
    for start, end in zip(starts.tolist(), ends.tolist(), strict=True):
        a = int(action[start])
        if a == NO_ACTION or ACTIONS[a] in NO_PROGRESS:
            continue
        try:
            h = progress_indicator(keypoints[start:end], a)
        except ModelInputError:
            continue  # an action without an indicator: no progress
        seen = np.isfinite(h)
        if not seen.any():
            continue
        p, rep = run_progress(keypoints[start:end], a)  # the simulator's convention
        progress[start:end] = np.where(seen, p, np.nan)
        repetition[start:end] = rep
    return progress, repetition
