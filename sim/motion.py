"""What the body does in one scene: subject, sampled keypoints and their labels.

``Motion`` is the hand-over to the pressure and sensor half of the simulator:
keypoints in the world (z up, floor at z = 0), the centre of mass, where the
person faces and which action they are doing, at ``rate_hz``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import numpy.typing as npt
from scotti.models.contract import KP
from scotti.models.progress import label_progress
from scotti.sim.skeleton import FOOT_LENGTH, Body
from scotti.sim.traits import TRAIT_NAMES, Traits, draw_traits

Array = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Subject:
    """One person: body size plus movement traits drawn from ``style_seed``.

    ``traits_given`` fixes traits by name (a scene's explicit values); the
    others are drawn (``scotti.sim.traits``). The common ones read as
    attributes: ``cadence_spm``, ``depth``, ``asymmetry``, ``tempo_variation``.
    """

    height_m: float
    mass_kg: float
    foot_length_m: float | None = None  # None: 0.152 x height
    style_seed: int = 0
    traits_given: Mapping[str, float | str] = field(default_factory=dict, hash=False)
    traits: Traits = field(init=False)

    def __post_init__(self) -> None:
        if self.foot_length_m is None:
            object.__setattr__(self, "foot_length_m", FOOT_LENGTH * self.height_m)
        given = dict(self.traits_given)
        object.__setattr__(self, "traits_given", given)
        object.__setattr__(self, "traits", draw_traits(self.style_seed, self.height_m, given))

    @property
    def foot_length(self) -> float:
        """Foot length in metres (given, or 0.152 x height)."""
        assert self.foot_length_m is not None  # set in __post_init__
        return self.foot_length_m

    @property
    def cadence_spm(self) -> float:
        return self.traits.cadence_spm

    @property
    def depth(self) -> float:
        return self.traits.depth

    @property
    def asymmetry(self) -> float:
        return self.traits.asymmetry

    @property
    def tempo_variation(self) -> float:
        return self.traits.tempo_variation

    @property
    def step_length_m(self) -> float:
        return self.traits.step_length_ratio * self.height_m

    def body(self) -> Body:
        """Segment lengths, stance width and toe-out of this person."""
        return Body.from_height(
            self.height_m,
            self.foot_length,
            stance_width=self.traits.stance_width_m,
            toe_out=(self.traits.toe_out_rad(0), self.traits.toe_out_rad(1)),
        )

    def as_dict(self) -> dict[str, float | int | str]:
        """Plain values for a session header: size, seed and every trait."""
        return {
            "height_m": self.height_m,
            "mass_kg": self.mass_kg,
            "foot_length_m": self.foot_length,
            "style_seed": self.style_seed,
            **{name: getattr(self.traits, name) for name in TRAIT_NAMES},
        }


@dataclass(frozen=True)
class Motion:
    """One scene sampled at ``rate_hz`` (16 Hz or an integer multiple of it)."""

    rate_hz: float
    world: Array  # (N, 19, 3) keypoints, world frame, metres, z up, floor z = 0
    com: Array  # (N, 3) centre of mass (Dempster segment masses)
    heading: Array  # (N,) radians, the way the person faces
    action: npt.NDArray[np.int64]  # (N,) index into ACTIONS, or NO_ACTION
    subject: Subject
    # (N, 2) height of the surface under the left and right foot (0 = floor,
    # the step's height while a foot is over a step); None means flat floor.
    ground_z: Array | None = None

    def __len__(self) -> int:
        return len(self.heading)

    @property
    def time_s(self) -> Array:
        return np.arange(len(self)) / self.rate_hz

    def pose_frame(self) -> Array:
        """Keypoints (N, 19, 3) with the origin on the floor under the mid-hip, x facing."""
        mid_hip = 0.5 * (self.world[:, KP["left_hip"]] + self.world[:, KP["right_hip"]])
        shifted = self.world - np.array([1.0, 1.0, 0.0]) * mid_hip[:, None, :]
        c, s = np.cos(self.heading)[:, None], np.sin(self.heading)[:, None]
        x, y = shifted[..., 0], shifted[..., 1]
        return np.stack([c * x + s * y, -s * x + c * y, shifted[..., 2]], axis=-1)

    def every(self, step: int) -> Motion:
        """Every ``step``-th frame (from an oversampled motion down to 16 Hz)."""
        return Motion(
            rate_hz=self.rate_hz / step,
            world=self.world[::step],
            com=self.com[::step],
            heading=self.heading[::step],
            action=self.action[::step],
            subject=self.subject,
            ground_z=None if self.ground_z is None else self.ground_z[::step],
        )


class Labels(NamedTuple):
    keypoints: npt.NDArray[np.float32]  # (N, 19, 3) pose frame
    action: npt.NDArray[np.int64]  # (N,)
    progress: npt.NDArray[np.float32]  # (N,) NaN where no action
    repetition: npt.NDArray[np.int32]  # (N,) -1 where no action


def labels(motion: Motion) -> Labels:
    """Ground truth per frame; progress and repetitions come from the skeleton alone."""
    keypoints = motion.pose_frame()
    progress, repetition = label_progress(keypoints, motion.action)
    return Labels(keypoints.astype(np.float32), motion.action.copy(), progress, repetition)
