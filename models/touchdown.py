"""Touch-downs: the frames where a foot lands, read from the keypoints alone.

Under the labelling convention (``PeakParams.step_cut = "after_landing"``,
models/progress.py) the stepping actions of ``TOUCHDOWN_CUT`` start a step on
the first frame whose prediction can see the landing (``step_starts``: the
frame after the first frame with load under the landing foot). Cut at the
indicator's peak, as the convention before it did, the wrap from 1 to 0 falls
half a frame after the landing on average for walking (on the landing frame or
the next, by the sampling's luck) and 1.5 frames before it for walking
backward, so a causal model can only hedge there: 0.5 on the frame after the
landing, three quarters of walking's
squared progress error (`python experiments/progress_error_sites.py`,
`python experiments/label_cuts.py`).

A foot is down while its lowest point (heel, big toe, small toe) is within
``DOWN_M`` of where that point rests in the run (its 5th percentile of
height), and up once that lowest point is more than ``UP_M`` above it;
between the two it keeps its state (hysteresis against mocap jitter). A
touch-down is the first down frame after the foot was up. In the simulator
the landings are the frames the insole first loads: the frame after each lies
+0.96 frames from the nearest first load for walking (spread 0.18), +0.94 for
walking backward and in place (spread 0.24 and 0.23; `python
experiments/label_cuts.py data/corpus21/realistic/subject-013.ses
--strike-share 0.05`, the "after landing" rows). Numpy only.
"""

from __future__ import annotations

from typing import Final

import numpy as np
import numpy.typing as npt
from scotti.models.contract import ACTIONS, KP

# Actions cut at touch-downs; the others (and side walking, whose repetition is
# a two-step cycle) keep the indicator's peaks (models/progress.py).
TOUCHDOWN_CUT: Final[frozenset[int]] = frozenset(
    ACTIONS.index(name) for name in ("walking", "backward_walking", "in_place_walking")
)
# A step starts this many frames after its landing: the model predicts frame t from
# frames t-T..t-1 (evaluation/replay.py; the daemon publishes for the frame to
# come), so frame L + 1 is the first whose input shows a landing at L. Cut on the
# landing frame itself, the wrap was as unanswerable as at the indicator's peak,
# one frame earlier: trained so (runs/v36-landing-s5), the model hedged on the
# frame before each landing (docs/generalisation.md, "Where a step starts").
SEEN_AFTER: Final = 1
DOWN_M: Final = 0.005  # a foot's lowest point this near its resting height: down
UP_M: Final = 0.010  # ... this far above it: up (between: as before)
REST_PERCENTILE: Final = 5.0
FOOT_POINTS: Final[tuple[tuple[int, ...], ...]] = (
    (KP["left_heel"], KP["left_big_toe"], KP["left_small_toe"]),
    (KP["right_heel"], KP["right_big_toe"], KP["right_small_toe"]),
)


def feet_down(keypoints: npt.ArrayLike) -> npt.NDArray[np.bool_] | None:
    """(N, 19, 3) metres -> (N, 2) whether each foot is down; None where a foot point
    is ever non-finite (masked keypoints show no landing)."""
    k = np.asarray(keypoints, dtype=np.float64)
    down = np.zeros((len(k), len(FOOT_POINTS)), dtype=bool)
    for side, points in enumerate(FOOT_POINTS):
        z = k[:, points, 2]
        if z.size == 0 or not np.isfinite(z).all():
            return None
        rest = np.percentile(z, REST_PERCENTILE, axis=0)
        lowest = (z - rest).min(axis=1)
        state = bool(lowest[0] <= UP_M)  # a run that starts mid-swing starts up
        for i, height in enumerate(lowest.tolist()):
            if height <= DOWN_M:
                state = True
            elif height > UP_M:
                state = False
            down[i, side] = state
    return down


def step_starts(keypoints: npt.ArrayLike, min_distance: int) -> npt.NDArray[np.int64] | None:
    """Where the stepping actions' repetitions start: ``SEEN_AFTER`` frames after each
    landing that leaves such a frame inside the run; None where the feet cannot be read."""
    landed = touchdowns(keypoints, min_distance)
    if landed is None:
        return None
    starts = landed + SEEN_AFTER
    return starts[starts < len(np.asarray(keypoints))]


def touchdowns(keypoints: npt.ArrayLike, min_distance: int) -> npt.NDArray[np.int64] | None:
    """Frames (ascending) where a foot lands, never the first; of two landings closer
    than ``min_distance`` frames the earlier stays. None where the feet cannot be read."""
    down = feet_down(keypoints)
    if down is None:
        return None
    landed = down[1:] & ~down[:-1]
    frames = np.sort(np.flatnonzero(landed.any(axis=1)) + 1)
    kept: list[int] = []
    for frame in frames.tolist():
        if not kept or frame - kept[-1] >= min_distance:
            kept.append(frame)
    return np.asarray(kept, dtype=np.int64)


def rise_from_cut(p: npt.NDArray[np.float64], *, starts_at_cut: bool) -> npt.NDArray[np.float64]:
    """One step's progress from the indicator, cut after a landing: it never falls
    before the next cut, and a step that starts at a cut starts at 0 (the indicator's
    top may lie before the cut: walking backward's, 2.5 frames)."""
    p = np.maximum.accumulate(p)
    if starts_at_cut and p[0] < 1.0:
        p = (p - p[0]) / (1.0 - p[0])
    return p
