"""The sole pressed into the insole: a Winkler foundation solved per frame.

Each point of the sole presses with ``p = k * max(0, w)``, ``w`` its
compression in mm, ``k`` the tissue's stiffness (kPa/mm): a Winkler
(elastic) foundation, the standard first model of soft tissue on a plate
(the elastic foundation model of Johnson 1985, Contact Mechanics). The foot moves as a rigid sole
with three degrees of freedom: how deep it sinks (``d``, mm), its pitch
(``alpha``, mm per m, forefoot down) and its roll (``beta``, mm per m,
medial edge down), so a point with height ``h``, pitch lever ``lever`` and
medial coordinate ``t`` is compressed by ``w = d + alpha * lever + beta * t - h``.

Newton's method finds (d, alpha, beta) such that the summed force equals the
foot's load and the centre of pressure the requested (s, t); the force is
piecewise linear in the unknowns, so Newton is an active-set iteration, run
on many problems at once (vectorised). Newton overshoots when more points
come into contact than its linear model knew of, so its steps are bounded.
The renderer solves a table of (load, COP) once per foot (by continuation,
each solve starting from its neighbour's solution) and interpolates every
frame's unknowns in it (:class:`SolutionTable`); the pressure of the
interpolated unknowns is rescaled to carry the load exactly, and its COP is
within a few millimetres of the request (tests/test_sim_contact.py).

Contact is partial by construction: a light load touches only the lowest
points of the sole; the toes touch when the COP goes forward.
"""

from __future__ import annotations

from typing import Final

import numpy as np

NEWTON_ITERATIONS: Final = 12
_LEAK: Final = 1e-3  # stiffness share kept on points out of contact in the Jacobian
MAX_STEP_MM: Final = 5.0  # largest change of any point's compression per iteration


class Contact:
    """The taxels a sole can touch and the solver over them.

    Arrays are per candidate taxel (m of them): foot coordinates ``s_m`` and
    ``t_m`` (metres), sole ``height_mm``, ``stiffness`` (kPa/mm), pitch
    ``lever_m``; ``area_m2`` is one taxel's area.
    """

    def __init__(
        self,
        s_m: np.ndarray,
        t_m: np.ndarray,
        height_mm: np.ndarray,
        stiffness: np.ndarray,
        lever_m: np.ndarray,
        area_m2: float,
    ) -> None:
        self.s_m = np.asarray(s_m, np.float64)
        self.t_m = np.asarray(t_m, np.float64)
        self.height_mm = np.asarray(height_mm, np.float64)
        self.stiffness = np.asarray(stiffness, np.float64)
        self.area_m2 = float(area_m2)
        lever = np.asarray(lever_m, np.float64)
        lever = lever - lever.mean()  # centred: better conditioned Newton steps
        ones = np.ones_like(lever)
        ka = self.stiffness * self.area_m2 * 1e3  # newtons per mm of compression
        self._affine = np.stack([ones, lever, self.t_m])  # (3, m): w = x @ affine - h
        moments = np.stack([ones, self.s_m, self.t_m])  # (3, m)
        self._moment_basis = (moments * ka).T.copy()  # (m, 3): force, force * s, force * t
        jac = moments[:, None, :] * self._affine[None, :, :] * ka  # (3, 3, m)
        self._jacobian_basis = jac.reshape(9, -1).T.copy()  # (m, 9)
        self._affine32 = self._affine.astype(np.float32)
        self._height32 = self.height_mm.astype(np.float32)
        self._stiffness32 = self.stiffness.astype(np.float32)
        # How far a unit change of each unknown moves a point at most (mm).
        self._reach = np.array([1.0, np.abs(lever).max(), np.abs(self.t_m).max()])

    def solve(
        self,
        load_n: np.ndarray,
        s_target: np.ndarray,
        t_target: np.ndarray,
        x0: np.ndarray | None = None,
        iterations: int = NEWTON_ITERATIONS,
        max_step_mm: float = MAX_STEP_MM,
    ) -> np.ndarray:
        """Unknowns (n, 3) = (d, alpha, beta) carrying ``load_n`` with its COP at (s, t).

        ``x0``: a starting guess (n, 3); None starts flat, just touching.
        ``max_step_mm``: no point's compression changes more than this per
        step. Newton overshoots when more points come into contact than its
        linear model knew of, so steps from a close guess are kept short.
        """
        load = np.asarray(load_n, dtype=np.float64)[:, None]
        s_t = np.asarray(s_target, dtype=np.float64)[:, None]
        t_t = np.asarray(t_target, dtype=np.float64)[:, None]
        n = len(load)
        if x0 is None:
            x = np.zeros((n, 3))
            x[:, 0] = self.height_mm.min() + 1.0
        else:
            x = np.array(x0, dtype=np.float64)
        for _ in range(iterations):
            w = x @ self._affine
            w -= self.height_mm
            active = w > 0.0
            np.maximum(w, 0.0, out=w)
            mom = w @ self._moment_basis  # (n, 3): force, force * s, force * t
            resid = np.concatenate(
                [mom[:, :1] - load, mom[:, 1:2] - s_t * mom[:, :1], mom[:, 2:] - t_t * mom[:, :1]],
                axis=1,
            )
            jb = (np.where(active, 1.0, _LEAK) @ self._jacobian_basis).reshape(n, 3, 3)
            jac = jb.copy()
            jac[:, 1] -= s_t * jb[:, 0]
            jac[:, 2] -= t_t * jb[:, 0]
            step = np.linalg.solve(jac, -resid[..., None])[..., 0]
            span = np.abs(step) @ self._reach
            step *= np.minimum(1.0, max_step_mm / np.maximum(span, 1e-12))[:, None]
            x += step
        return x

    def pressure(self, x: np.ndarray, load_n: np.ndarray) -> np.ndarray:
        """Pressure (n, m) in kPa of the unknowns ``x``, rescaled to carry ``load_n`` exactly."""
        # einsum, not matmul: a (frames x 3) @ (3 x taxels) product that
        # OpenBLAS would spread over threads, slower than one core on a busy host.
        w: np.ndarray = np.einsum("nk,km->nm", np.asarray(x, np.float32), self._affine32)
        w -= self._height32
        np.maximum(w, 0.0, out=w)
        w *= self._stiffness32  # kPa
        force = w.sum(axis=1, dtype=np.float64) * (self.area_m2 * 1e3)
        load = np.asarray(load_n, dtype=np.float64)
        scale = np.where(force > 0.0, load / np.maximum(force, 1e-12), 0.0)
        w *= scale.astype(np.float32)[:, None]
        return w


class SolutionTable:
    """Solutions on a grid of (load, cop_u, cop_medial), looked up trilinearly.

    The unknowns are smooth in the load and the COP, so a table built once
    per foot puts every frame's Newton start within a fraction of a
    millimetre; a few Newton steps (or none) finish the job.
    """

    def __init__(
        self, loads_n: np.ndarray, cop_u: np.ndarray, cop_medial: np.ndarray, x: np.ndarray
    ) -> None:
        self.axes = (np.log(loads_n), np.asarray(cop_u), np.asarray(cop_medial))
        self.x = x  # (L, U, V, 3)

    def lookup(self, load_n: np.ndarray, cop_u: np.ndarray, cop_medial: np.ndarray) -> np.ndarray:
        """(n, 3) interpolated unknowns; inputs outside the grid take its edge."""
        index, frac = [], []
        for axis, v in zip(
            self.axes, (np.log(np.maximum(load_n, 1e-9)), cop_u, cop_medial), strict=True
        ):
            pos = np.interp(v, axis, np.arange(len(axis)))
            i = np.minimum(pos.astype(np.int64), len(axis) - 2)
            index.append(i)
            frac.append((pos - i)[:, None])
        (i, j, k), (fi, fj, fk) = index, frac
        x = self.x
        out = np.zeros((len(i), 3))
        for di, wi in ((0, 1 - fi), (1, fi)):
            for dj, wj in ((0, 1 - fj), (1, fj)):
                for dk, wk in ((0, 1 - fk), (1, fk)):
                    out += wi * wj * wk * x[i + di, j + dj, k + dk]
        return out
