"""Steer the whole body's centre of mass, not the hips, along a drawn height.

The vertical ground reaction force is ``m (g + z_com'')``. Recipes that draw
a force (a landing, a step up) draw it for the COM; the arms swinging, the
trunk leaning and a leg lifting move the COM against the hips, so the hips
are moved until the COM follows. Three fixed-point steps suffice: the trunk,
head and arms (two thirds of the mass) move one to one with the hips and the
legs about half, so each step leaves about a quarter of the error.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scotti.sim.actions.base import finalize
from scotti.sim.skeleton import Array, Body, PoseParams, center_of_mass, pose_keypoints


def com_z(body: Body, p: PoseParams) -> Array:
    """Height (N,) of the COM of the finalised pose."""
    return np.asarray(center_of_mass(body, pose_keypoints(body, finalize(body, p)))[:, 2])


def take(p: PoseParams, idx: npt.NDArray[np.intp]) -> PoseParams:
    """The frames ``idx`` of ``p``."""
    return PoseParams(**{n: getattr(p, n)[idx] for n in PoseParams.__dataclass_fields__})


def steer_com_z(
    body: Body,
    p: PoseParams,
    target: Array,
    window: npt.NDArray[np.bool_],
    feet_follow: npt.NDArray[np.bool_] | None = None,
    iterations: int = 3,
) -> PoseParams:
    """``p`` with the pelvis raised or lowered inside ``window`` so that the COM is at ``target``.

    Where ``feet_follow`` (N,) is set (in the air) both ankles move with the
    pelvis; elsewhere the feet stay where they stand. Only the window's
    frames are posed (the kinematics are frame by frame).
    """
    idx = np.flatnonzero(window)
    if idx.size == 0:
        return p
    part = take(p, idx)
    follow = None if feet_follow is None else feet_follow[idx]
    goal = target[idx]
    for _ in range(iterations):
        error = goal - com_z(body, part)
        pelvis = part.pelvis.copy()
        pelvis[:, 2] += error
        ankle = part.ankle
        if follow is not None:
            ankle = ankle.copy()
            ankle[follow, :, 2] += error[follow, None]
        part = part.replace(pelvis=pelvis, ankle=ankle)
    pelvis, ankle = p.pelvis.copy(), p.ankle.copy()
    pelvis[idx], ankle[idx] = part.pelvis, part.ankle
    return p.replace(pelvis=pelvis, ankle=ankle)
