"""Fast exact test of the MAV ball against OCCUPIED grid cells (thesis eq. A-3), for the global primitives search.

A point collides when its ball of radius ``reach`` (m) overlaps an OCCUPIED cell's square/cube — the test of
OccupancyGrid.collides. Two masks over the cells, built once per grid version, screen points by the cell that holds
them: a cell is *maybe* bad if an OCCUPIED cell's box is closer than reach to some point of it, and *surely* bad if
an OCCUPIED box is closer than reach to every point of it. Only points in maybe-but-not-surely cells get the exact
point-to-box distances, and only against the OCCUPIED cells within reach.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from pbdyn.perception.grid import OCCUPIED


def cell_offsets(reach: float, res: float, dims: int, every_point: bool) -> np.ndarray:
    """Integer cell offsets [W, d] (cells of size res, m) from a cell whose box is closer than reach (m) to some
    point of the centre cell (every_point False), or to every point of it (every_point True)."""
    k = int(math.ceil(reach / res)) + 1
    off = np.array(list(itertools.product(range(-k, k + 1), repeat=dims)), dtype=np.int64)
    gap = (np.abs(off) if every_point else np.maximum(np.abs(off) - 1, 0)) * res
    return off[np.einsum("wd,wd->w", gap, gap) < reach * reach]


class StaticScreen:
    """The screening masks of one grid version for ball radius ``reach`` (m); see the module docstring."""

    def __init__(self, grid, reach: float):
        self.grid = grid
        self.version = grid.version
        self.reach = float(reach)
        d = grid.dims
        self.occupied = grid.cells == OCCUPIED
        self.maybe = self._dilate(cell_offsets(reach, grid.res, d, False))
        self.surely = self._dilate(cell_offsets(reach, grid.res, d, True))
        self._near = cell_offsets(reach, grid.res, d, False)
        self._shape = np.asarray(grid.shape)

    def _dilate(self, offsets: np.ndarray) -> np.ndarray:
        mask = np.zeros(self.grid.shape, dtype=bool)
        occ = np.argwhere(self.occupied)
        if occ.shape[0]:
            cells = (occ[:, None, :] + offsets[None, :, :]).reshape(-1, occ.shape[1])
            cells = cells[np.all((cells >= 0) & (cells < np.asarray(self.grid.shape)), axis=1)]
            mask[tuple(cells.T)] = True
        return mask

    def valid_for(self, grid) -> bool:
        """True if these masks describe the grid's current contents."""
        return grid is self.grid and grid.version == self.version

    def box_maybe(self, lo: np.ndarray, hi: np.ndarray) -> bool:
        """False if no point of the box [lo, hi] (m) can collide."""
        i_lo, i_hi = self.grid.index(np.stack([lo, hi]))
        return bool(self.maybe[tuple(slice(a, b + 1) for a, b in zip(i_lo, i_hi))].any())

    def bad(self, pts: np.ndarray) -> np.ndarray:
        """Per point [K, d] (m): True if its ball overlaps an OCCUPIED cell (exact)."""
        grid = self.grid
        out = np.zeros(pts.shape[0], dtype=bool)
        if pts.shape[0] == 0:
            return out
        idx = grid.index(pts)
        cell = tuple(idx.T)
        sure = self.surely[cell]
        out |= sure
        band = np.flatnonzero(self.maybe[cell] & ~sure)
        if band.size:
            cand = idx[band, None, :] + self._near[None]                               # [B, W, d]
            inside = np.all((cand >= 0) & (cand < self._shape), axis=2)
            hit = np.zeros(inside.shape, dtype=bool)
            hit[inside] = self.occupied[tuple(cand[inside].T)]
            k, w = np.nonzero(hit)
            if k.size:
                p = pts[band[k]]
                lo = grid.origin + cand[k, w] * grid.res
                gap = np.maximum(np.maximum(lo - p, p - (lo + grid.res)), 0.0)
                close = np.einsum("kd,kd->k", gap, gap) < self.reach * self.reach
                out[band[np.unique(k[close])]] = True
        return out
