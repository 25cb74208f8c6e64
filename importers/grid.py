"""Any insole grid onto the contract's 32 x 22: orientation, then area-weighted remapping.

First each foot's grid is turned into our orientation (models/insole.py):
transposed if its rows run across the foot, rows flipped unless row 0 is at
the toes, columns flipped unless column 0 is medial. Then both grids are
taken to span the same insole (sensing length x width), and each of our
taxels gets the mean of the source taxels under it, weighted by the area
they share with it (conservative remapping). Pressure is a density, so this
keeps the integral: the force, sum(pressure x area), is the same on both
grids. The weights are separable: one (32, rows) matrix along the foot and
one (22, cols) across it, ``out = R @ frame @ C.T``.

Source taxels outside the source's outline (a 0 in its outline file) are
zeroed before remapping; ours outside our outline are zeroed after, as the
shipped model never saw pressure there.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scotti.models.contract import FRAME_COLS, FRAME_ROWS
from scotti.models.insole import insole_mask


def overlap_weights(source: int, target: int) -> np.ndarray:
    """(target, source): share of target cell i covered by source cell j; rows sum to 1.

    Both divide [0, 1] into equal cells. Example: 2 source cells onto 3
    target cells gives [[1, 0], [1/2, 1/2], [0, 1]].
    """
    s_edges = np.linspace(0.0, 1.0, source + 1)
    t_edges = np.linspace(0.0, 1.0, target + 1)
    lo = np.maximum(t_edges[:-1, None], s_edges[None, :-1])
    hi = np.minimum(t_edges[1:, None], s_edges[None, 1:])
    overlap = np.clip(hi - lo, 0.0, None)  # (target, source) lengths
    return np.asarray(overlap * target)  # / target cell length 1/target


@dataclass(frozen=True)
class Orientation:
    """How one foot's grid is stored (see ``importers.config.FootGrid``)."""

    toes_first_row: bool = True
    medial_first_col: bool = True
    transpose: bool = False

    def apply(self, frames: np.ndarray) -> np.ndarray:
        """(N, rows, cols) as stored -> (N, rows', cols') toes at row 0, medial at column 0."""
        x = np.swapaxes(frames, 1, 2) if self.transpose else frames
        if not self.toes_first_row:
            x = x[:, ::-1, :]
        if not self.medial_first_col:
            x = x[:, :, ::-1]
        return x

    def apply_mask(self, mask: np.ndarray) -> np.ndarray:
        return np.asarray(self.apply(mask[None])[0])


class GridMapper:
    """One foot's source grid (in our orientation) onto 32 x 22, outline applied."""

    def __init__(self, rows: int, cols: int, source_mask: np.ndarray | None = None) -> None:
        self.rows, self.cols = rows, cols
        self.along = overlap_weights(rows, FRAME_ROWS).astype(np.float32)  # (32, rows)
        self.across_t = overlap_weights(cols, FRAME_COLS).T.astype(np.float32)  # (cols, 22)
        self.source_mask = None if source_mask is None else source_mask.astype(np.float32)
        self.target_mask = insole_mask().astype(np.float32)

    def __call__(self, frames: np.ndarray) -> np.ndarray:
        """(N, rows, cols) -> (N, 32, 22) float32 area-weighted means, outlines applied."""
        x = np.asarray(frames, dtype=np.float32)
        if self.source_mask is not None:
            x = x * self.source_mask
        out = self.along @ x @ self.across_t  # (32, rows) @ (N, rows, cols) @ (cols, 22)
        out *= self.target_mask
        return np.asarray(out)
