"""Where a set's label ends: the still standing at its edges (models/contract.py,
"The labelling convention").

A run of a repeated action may begin and end standing still: the recipe's
moment of getting ready, the hold at the top of its last repetition, or a
segment file drawn loosely around the set. At most ``SET_EDGE_REST_S`` of that
stillness next to the set's first and last movement keeps the set's label;
the stillness beyond it becomes ``STANDING``.

After the last movement of a set of ``PAUSING_ACTIONS`` the still standing is the
set's for exactly ``SET_EDGE_REST_S``, as a pause's first second is: standing that the
source labelled ``STANDING`` right after the run, still and straight-legged, is taken
into the set up to the bound. Without it a set's end kept only the recipe's hold and
the label told an end from a pause by what came after, which no model reading the past
can (experiments/set_switches.py).

A pause between movements inside the run is held to the same bound: its first
``SET_EDGE_REST_S`` is the set's, the rest, up to the next movement, is
``STANDING`` when the person stands straight-legged in it (both knees bent less
than ``STANDING_KNEE_FLEXION_DEG``). Why: a model reads the past only, and
stillness after a set's last repetition looks like a pause until the next
repetition comes or does not; under a convention where a pause of any length is
the set, the standing after every set was unanswerable (the model named the set
for 1.4-2.1 s after its end, experiments/set_end_latency.py). A held crouch (a
jump's landing, a lunge held low) is not standing and stays the set's.

Stillness is read from the keypoints of the run itself (pose frame, metres):
a frame is still when no keypoint moved faster than ``STILL_SPEED_MPS`` since
the previous frame (the run's first frame: up to the second). A frame with no
keypoint seen in both is unknown, and an edge with an unknown frame is left as
it is: what the keypoints do not show is not relabelled. A run in which nothing
moves at all is no set: seen and straight-legged throughout it is ``STANDING``
(the same motion as standing gets standing's label), a held crouch keeps its
label. Numpy only.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scotti.models.contract import (
    ACTIONS,
    BONES,
    JOINT_ANGLES,
    NUM_KEYPOINTS,
    PAUSING_ACTIONS,
    SET_EDGE_REST_S,
    STANDING,
    STANDING_KNEE_FLEXION_DEG,
    STILL_SPEED_MPS,
    has_progress,
)
from scotti.models.errors import ModelInputError
from scotti.models.metrics import joint_angles_deg

IntArray = npt.NDArray[np.int64]
# Where the knees are among the contract's joint angles: thigh to shank, left then right.
_KNEES = [
    JOINT_ANGLES.index(
        (
            BONES.index((f"{side}_hip", f"{side}_knee")),
            BONES.index((f"{side}_knee", f"{side}_ankle")),
        )
    )
    for side in ("left", "right")
]


def frame_speeds(keypoints: npt.ArrayLike, rate_hz: float) -> npt.NDArray[np.float64]:
    """(N,) the fastest keypoint's speed (m/s) into each frame from the one before;
    frame 0 takes frame 1's. NaN where no keypoint is seen in both frames."""
    k = np.asarray(keypoints, dtype=np.float64)
    if k.ndim != 3 or k.shape[1:] != (NUM_KEYPOINTS, 3):
        msg = f"keypoints must be (N, {NUM_KEYPOINTS}, 3), got {k.shape}"
        raise ModelInputError(msg)
    if len(k) < 2:
        return np.full(len(k), np.nan)
    step = np.linalg.norm(np.diff(k, axis=0), axis=-1)  # (N-1, 19), NaN where unseen
    seen = np.isfinite(step)
    fastest = np.where(seen, step, -np.inf).max(axis=1) * rate_hz
    fastest = np.where(seen.any(axis=1), fastest, np.nan)
    return np.asarray(np.r_[fastest[0], fastest], dtype=np.float64)


def set_edges(
    keypoints: npt.ArrayLike,
    actions: npt.ArrayLike,
    rate_hz: float,
    segment: npt.ArrayLike | None = None,
) -> IntArray:
    """``actions`` with every run of a repeated action held to the convention at its edges.

    ``keypoints`` (N, 19, 3) pose frame, metres; ``actions`` (N,) ints; ``segment``
    (N,) optional ids of stretches recorded without a gap (a run never spans two).
    Returns a new array; transitions are kept, and so is a pause inside a run up to
    ``SET_EDGE_REST_S`` (beyond it, standing straight-legged is ``STANDING``); standing
    is kept but for the second after a pausing set's last movement.
    """
    k = np.asarray(keypoints, dtype=np.float64)
    out = np.array(actions, dtype=np.int64, copy=True)
    if out.shape != (len(k),):
        msg = f"actions must be ({len(k)},), got {out.shape}"
        raise ModelInputError(msg)
    part = np.zeros(len(k), np.int64) if segment is None else np.asarray(segment)
    keep = round(SET_EDGE_REST_S * rate_hz)
    given = out.copy()  # the source's labels (out[start] may turn standing: a long lead)
    for start, end in _runs(out, part):
        action = int(given[start])
        if not has_progress(action):
            continue
        speed = frame_speeds(k[start:end], rate_hz)
        moving = np.flatnonzero(speed >= STILL_SPEED_MPS)
        if moving.size == 0:
            # Nothing moved: no set was done, whatever the source said (a squat of
            # depth 0 is a person standing). Seen and straight-legged throughout, the
            # run is the standing it shows; otherwise (a held crouch, an unseen frame)
            # there is nothing to measure its edges from and it keeps its label.
            if np.isfinite(speed).all() and _straight_legged(k[start:end]).all():
                out[start:end] = STANDING
            continue
        first, last = int(moving[0]), int(moving[-1])
        lead_known = bool(np.isfinite(speed[:first]).all())
        tail_known = bool(np.isfinite(speed[last + 1 :]).all())
        if lead_known and first > keep:
            out[start : start + first - keep] = STANDING
        if tail_known and end - start - 1 - last > keep:
            out[start + last + 1 + keep : end] = STANDING
        if tail_known and ACTIONS[action] in PAUSING_ACTIONS:
            wanted = keep - (end - start - 1 - last)
            taken = _standing_after(k, given, part, end, wanted, rate_hz)
            out[end : end + taken] = action
        straight = _straight_legged(k[start:end])
        for before, after in zip(moving[:-1].tolist(), moving[1:].tolist(), strict=True):
            beyond = slice(before + 1 + keep, after)  # the pause's frames past the bound
            seen = np.isfinite(speed[before + 1 : after]).all()
            if after - before - 1 > keep and seen and straight[beyond].all():
                out[start + beyond.start : start + beyond.stop] = STANDING
    return out


def _standing_after(
    k: npt.NDArray[np.float64],
    given: IntArray,
    part: npt.NDArray[np.generic],
    end: int,
    wanted: int,
    rate_hz: float,
) -> int:
    """How many of the up to ``wanted`` frames from ``end`` on are standing as a pause
    stands: labelled ``STANDING``, in the segment of frame ``end - 1``, still (measured
    from the frame before) and straight-legged; the count stops at the first that is not."""
    if wanted <= 0 or end >= len(k):
        return 0
    stop = min(end + wanted, len(k))
    window = k[end - 1 : stop]
    speed = frame_speeds(window, rate_hz)[1:]  # each frame's speed from the one before
    ok = (
        (given[end:stop] == STANDING)
        & (part[end:stop] == part[end - 1])
        & (speed < STILL_SPEED_MPS)  # NaN (unseen) is not still
        & _straight_legged(window[1:])
    )
    bad = np.flatnonzero(~ok)
    return int(bad[0]) if bad.size else stop - end


def knee_flexion_deg(keypoints: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """(N, 2) left and right knee flexion in degrees (0: straight), NaN where unseen:
    the knees among the contract's joint angles (models/metrics.py)."""
    return joint_angles_deg(keypoints)[..., _KNEES]


def _straight_legged(keypoints: npt.NDArray[np.float64]) -> npt.NDArray[np.bool_]:
    """(N,) whether both knees are seen and bent less than ``STANDING_KNEE_FLEXION_DEG``."""
    with np.errstate(invalid="ignore"):
        return np.asarray((knee_flexion_deg(keypoints) < STANDING_KNEE_FLEXION_DEG).all(axis=1))


def _runs(actions: IntArray, segment: npt.NDArray[np.generic]) -> list[tuple[int, int]]:
    """[start, end) of each maximal run of one action within one segment."""
    if actions.size == 0:
        return []
    change = (actions[1:] != actions[:-1]) | (segment[1:] != segment[:-1])
    starts = np.flatnonzero(np.r_[True, change])
    ends = np.r_[starts[1:], actions.size]
    return list(zip(starts.tolist(), ends.tolist(), strict=True))
