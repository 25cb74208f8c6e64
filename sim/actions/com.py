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
    pelvis; elsewhere the feet stay where they stand.
    """
    com = com_z(body, p)
    for _ in range(iterations):
        error = np.where(window, target - com, 0.0)
        pelvis = p.pelvis.copy()
        pelvis[:, 2] += error
        ankle = p.ankle
        if feet_follow is not None:
            ankle = ankle.copy()
            ankle[feet_follow, :, 2] += error[feet_follow, None]
        p = p.replace(pelvis=pelvis, ankle=ankle)
        com = com_z(body, p)
    return p
