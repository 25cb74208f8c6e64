"""Cells on our grid: shared area of polygons, tiles of the sole, outlines fitted to ours.

Coordinates are (along, across) shares of our 32 x 22 box: along 0 at the
toe tip, 1 at the heel end; across 0 medial, 1 lateral (models/insole.py,
whose ``u`` is ``1 - along``). Each taxel is split into ``supersample`` x
``supersample`` points; a taxel's share of a cell is the share of its points
in it. Taxels outside our outline (``insole_mask``) get none.
"""

from __future__ import annotations

from typing import Final

import numpy as np
from scotti.models.contract import FRAME_COLS, FRAME_ROWS
from scotti.models.insole import OUTLINE_LATERAL, OUTLINE_MEDIAL, OUTLINE_U, insole_mask

TAXELS: Final = FRAME_ROWS * FRAME_COLS
SUPERSAMPLE: Final = 8  # points per taxel side
TILE_SOFTNESS: Final = 0.3  # soft tile edge, as a share of the sensors' median spacing
_STATIONS: Final = np.linspace(0.0, 1.0, 401)  # along, where outlines are compared
_MIN_SPAN_RATIO: Final = 0.6  # narrower than this share of ours: keep a wider station's stretch
_TILE_FIT_STEPS: Final = 60  # Newton steps fitting tile sizes to the vendor's areas
_TILE_FIT_TOLERANCE: Final = 0.005  # tile size within 0.5 % of its area's share
_TILE_FIT_SUPERSAMPLE: Final = 4


def polygon_area(p: np.ndarray) -> float:
    x, y = p[:, 0], p[:, 1]
    return float(0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y)))


def centroid(p: np.ndarray) -> np.ndarray:
    x, y = p[:, 0], p[:, 1]
    cross = x * np.roll(y, -1) - np.roll(x, -1) * y
    a = cross.sum() / 2.0
    if abs(a) < 1e-12:
        return np.asarray(p.mean(axis=0))
    cx = ((x + np.roll(x, -1)) * cross).sum() / (6.0 * a)
    cy = ((y + np.roll(y, -1)) * cross).sum() / (6.0 * a)
    return np.array([cx, cy])


def our_edges(along: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Our outline's medial and lateral edge (across) at these along stations."""
    u = 1.0 - along
    return np.interp(u, OUTLINE_U, OUTLINE_MEDIAL), np.interp(u, OUTLINE_U, OUTLINE_LATERAL)


def _edges_of(polys: list[np.ndarray], stations: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The cells' joint medial and lateral edge at each station (nearest where none)."""
    lo = np.full(stations.shape, np.inf)
    hi = np.full(stations.shape, -np.inf)
    for p in polys:
        for (a0, c0), (a1, c1) in zip(np.roll(p, 1, axis=0), p, strict=True):
            if a0 == a1:
                hit = stations == a0
                lo[hit] = np.minimum(lo[hit], min(c0, c1))
                hi[hit] = np.maximum(hi[hit], max(c0, c1))
                continue
            hit = (stations >= min(a0, a1)) & (stations <= max(a0, a1))
            at = c0 + (stations[hit] - a0) * (c1 - c0) / (a1 - a0)
            lo[hit] = np.minimum(lo[hit], at)
            hi[hit] = np.maximum(hi[hit], at)
    known = np.flatnonzero(np.isfinite(lo))
    nearest = known[np.abs(np.arange(stations.size)[:, None] - known[None, :]).argmin(axis=1)]
    return lo[nearest], hi[nearest]


def _densify(p: np.ndarray, per_edge: int = 8) -> np.ndarray:
    t = np.arange(per_edge)[:, None] / per_edge
    starts, ends = p, np.roll(p, -1, axis=0)
    return np.asarray((starts[:, None, :] * (1 - t) + ends[:, None, :] * t).reshape(-1, 2))


def fit_to_outline(polys: list[np.ndarray]) -> list[np.ndarray]:
    """The cells, their insole fitted to our outline station by station.

    Along stays (both insoles run from toe tip to heel end); across, at each
    station, the cells' joint medial..lateral span is stretched onto our
    outline's. So the vendor's insole lies where ours does, and no cell is
    cut off by a difference of shape (a pedar insole is straight on its
    lateral hindfoot edge, ours curves in). Where the vendor's insole is
    much narrower than ours (the last millimetres of a round heel or toe),
    the stretch of the nearest wider station is kept, so a round end stays
    round instead of being pulled square. Edges are densified first, as
    the fit bends them.
    """
    v_lo, v_hi = _edges_of(polys, _STATIONS)
    o_lo, o_hi = our_edges(_STATIONS)
    good = np.flatnonzero((v_hi - v_lo) >= _MIN_SPAN_RATIO * (o_hi - o_lo))
    nearest = good[np.abs(np.arange(_STATIONS.size)[:, None] - good[None, :]).argmin(axis=1)]
    v_lo, v_hi, o_lo, o_hi = v_lo[nearest], v_hi[nearest], o_lo[nearest], o_hi[nearest]
    out = []
    for p in polys:
        d = _densify(p)
        a = d[:, 0]
        m_v, l_v = np.interp(a, _STATIONS, v_lo), np.interp(a, _STATIONS, v_hi)
        m_o, l_o = np.interp(a, _STATIONS, o_lo), np.interp(a, _STATIONS, o_hi)
        across = m_o + (d[:, 1] - m_v) / (l_v - m_v) * (l_o - m_o)
        out.append(np.stack([a, across], axis=1))
    return out


def _sub_points(supersample: int) -> tuple[np.ndarray, np.ndarray]:
    """(along, across) of every point, each (32 S, 22 S); taxel (r, c) owns S x S of them."""
    along = (np.arange(FRAME_ROWS * supersample) + 0.5) / (FRAME_ROWS * supersample)
    across = (np.arange(FRAME_COLS * supersample) + 0.5) / (FRAME_COLS * supersample)
    a, c = np.meshgrid(along, across, indexing="ij")
    return a, c


def _per_taxel(share: np.ndarray, supersample: int) -> np.ndarray:
    """(32 S, 22 S, n) point shares -> (704, n) taxel means, our outline applied."""
    s, n = supersample, share.shape[-1]
    blocks = share.reshape(FRAME_ROWS, s, FRAME_COLS, s, n).mean(axis=(1, 3))
    return np.asarray(blocks.reshape(TAXELS, n) * insole_mask().reshape(TAXELS, 1))


def _inside(px: np.ndarray, py: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Even-odd rule: which points lie inside the polygon (k, 2)."""
    inside = np.zeros(px.shape, dtype=bool)
    x, y = poly[:, 0], poly[:, 1]
    for k in range(len(poly)):
        x0, y0, x1, y1 = x[k - 1], y[k - 1], x[k], y[k]
        if y0 == y1:
            continue
        crosses = (y0 > py) != (y1 > py)
        at = x0 + (py - y0) * (x1 - x0) / (y1 - y0)
        inside ^= crosses & (px < at)
    return inside


def outline_membership(
    outlines: tuple[np.ndarray, ...], supersample: int = SUPERSAMPLE
) -> np.ndarray:
    """(704, n): share of each of our taxels inside each cell's polygon."""
    along, across = _sub_points(supersample)
    share = np.zeros((*along.shape, len(outlines)), dtype=np.float32)
    for i, poly in enumerate(outlines):
        lo, hi = poly.min(axis=0), poly.max(axis=0)
        box = (along >= lo[0]) & (along <= hi[0]) & (across >= lo[1]) & (across <= hi[1])
        hit = np.zeros(along.shape, dtype=bool)
        hit[box] = _inside(along[box], across[box], poly)
        share[..., i] = hit
    return _per_taxel(share, supersample)


def tile_membership(
    centres: np.ndarray,
    aspect: float,
    areas: np.ndarray | None = None,
    supersample: int = SUPERSAMPLE,
) -> np.ndarray:
    """(704, n): share of each taxel of our outline in each sensor's soft tile.

    A point goes to the nearest sensor (across scaled by the insole's width /
    length, so distances are millimetres up to one factor), with a soft edge:
    shares ``softmax((w_i - d_i^2) / 2 s^2)``. With ``areas``, the weights
    ``w_i`` are fitted so that each tile's size is in proportion to its
    sensor's area (a power diagram): the tiles are the regions the vendor's
    areas stand for. Every point's shares sum to 1: the tiles split our
    outline between the sensors.
    """
    ctr = np.stack([centres[:, 0], centres[:, 1] * aspect], axis=1)
    two_s2 = 2.0 * (TILE_SOFTNESS * _median_spacing(ctr)) ** 2
    weights = np.zeros(len(centres))
    if areas is not None:  # fitted on a coarser set of points: the same tiles, sooner
        d2, _ = _tile_distances(ctr, aspect, _TILE_FIT_SUPERSAMPLE)
        target = np.asarray(areas, dtype=np.float64) / np.sum(areas) * len(d2)
        for _ in range(_TILE_FIT_STEPS):
            share = _soft_tiles(weights, d2, two_s2)
            have = share.sum(axis=0)
            if np.max(np.abs(have / target - 1.0)) < _TILE_FIT_TOLERANCE:
                break
            slope = (share * (1.0 - share)).sum(axis=0) / two_s2  # d have / d weight
            weights += (target - have) / np.maximum(slope, 1e-12)  # Newton, per tile
            weights -= weights.mean()
    d2, inside = _tile_distances(ctr, aspect, supersample)
    full = np.zeros((inside.size, len(centres)))
    full[inside] = _soft_tiles(weights, d2, two_s2)
    along, _ = _sub_points(supersample)
    return _per_taxel(full.reshape(*along.shape, -1), supersample)


def _tile_distances(
    ctr: np.ndarray, aspect: float, supersample: int
) -> tuple[np.ndarray, np.ndarray]:
    """Squared distances (P, n) from the points of our outline to the sensors, and those points."""
    along, across = _sub_points(supersample)
    inside = np.repeat(np.repeat(insole_mask(), supersample, 0), supersample, 1).ravel()
    pts = np.stack([along.ravel(), across.ravel() * aspect], axis=1)[inside]
    return ((pts[:, None, :] - ctr[None, :, :]) ** 2).sum(axis=2), inside


def _soft_tiles(weights: np.ndarray, d2: np.ndarray, two_s2: float) -> np.ndarray:
    logit = (weights - d2) / two_s2
    e = np.exp(logit - logit.max(axis=1, keepdims=True))
    return np.asarray(e / e.sum(axis=1, keepdims=True))


def _median_spacing(ctr: np.ndarray) -> float:
    if len(ctr) < 2:
        return 1.0
    d = np.sqrt(((ctr[:, None] - ctr[None]) ** 2).sum(axis=2))
    np.fill_diagonal(d, np.inf)
    return float(np.median(d.min(axis=1)))


def nearest_outline_taxel(point: np.ndarray) -> int:
    """Index (0..703) of the taxel of our outline whose centre is nearest (along, across)."""
    live = np.flatnonzero(insole_mask().ravel())
    rows, cols = np.divmod(live, FRAME_COLS)
    d2 = ((rows + 0.5) / FRAME_ROWS - point[0]) ** 2 + ((cols + 0.5) / FRAME_COLS - point[1]) ** 2
    return int(live[int(np.argmin(d2))])


def onto_outline(points: np.ndarray) -> np.ndarray:
    """(n, 2) positions; one on a taxel outside our outline moves to the nearest one inside."""
    out = np.array(points, dtype=np.float64)
    mask = insole_mask()
    for i, (a, c) in enumerate(out):
        row = min(max(int(a * FRAME_ROWS), 0), FRAME_ROWS - 1)
        col = min(max(int(c * FRAME_COLS), 0), FRAME_COLS - 1)
        if not mask[row, col]:
            row, col = divmod(nearest_outline_taxel(out[i]), FRAME_COLS)
            out[i] = [(row + 0.5) / FRAME_ROWS, (col + 0.5) / FRAME_COLS]
    return out


def extents(member: np.ndarray) -> np.ndarray:
    """(n, 2) along/across extent of the taxels where each cell holds the largest share."""
    rows, cols = np.divmod(np.arange(TAXELS), FRAME_COLS)
    top = member.argmax(axis=1)
    live = member.max(axis=1) > 0
    out = np.zeros((member.shape[1], 2))
    for i in range(member.shape[1]):
        mine = live & (top == i)
        if mine.any():
            out[i] = [
                (rows[mine].max() - rows[mine].min() + 1) / FRAME_ROWS,
                (cols[mine].max() - cols[mine].min() + 1) / FRAME_COLS,
            ]
    return out
