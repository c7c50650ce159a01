"""The MAV's occupancy grid (thesis 2-4-2): UNKNOWN / FREE / OCCUPIED cells over the arena plus a 1-cell border.

Cell (i, j[, k]) covers [lo + (i - 1) * res, lo + i * res) on each axis, so index 0 and index n + 1 are the wall
border just outside the arena. Only static geometry (pillars, boxes, walls) is written: dynamic obstacles are
tracked, not mapped. OCCUPIED is sticky (static geometry never moves), so a ray grazing a partly occupied cell
never frees it again.
"""

from __future__ import annotations

import itertools

import numpy as np

from pbdyn.jit import njit

UNKNOWN = np.int8(-1)
FREE = np.int8(0)
OCCUPIED = np.int8(1)


class OccupancyGrid:
    """A d-dimensional occupancy grid with resolution ``res`` (m) over the box [lo, hi] plus a 1-cell border."""

    def __init__(self, lo, hi, res: float = 1.0):
        self.lo = np.asarray(lo, dtype=float)
        self.hi = np.asarray(hi, dtype=float)
        self.res = float(res)
        if self.lo.shape != self.hi.shape or self.lo.ndim != 1 or np.any(self.hi <= self.lo) or self.res <= 0:
            raise ValueError("OccupancyGrid needs lo < hi of one shape [d] and res > 0")
        inner = np.ceil((self.hi - self.lo) / self.res - 1e-9).astype(int)
        self.shape = tuple(int(n) + 2 for n in inner)
        self.cells = np.full(self.shape, UNKNOWN, dtype=np.int8)
        self.origin = self.lo - self.res  # world coordinate of the corner of cell 0
        self.version = 0  # incremented whenever a cell becomes OCCUPIED
        self._last = np.asarray(self.shape, dtype=np.int64) - 1
        self._strides = np.cumprod((self.shape[1:] + (1,))[::-1])[::-1].astype(np.int64)  # C-order, in cells
        self._offset_cache: dict[tuple, tuple] = {}
        self._near_cache: tuple = (None, {})   # (OCCUPIED mask it was built from, {h: dilated mask})

    @property
    def dims(self) -> int:
        """Spatial dimension d."""
        return self.lo.shape[0]

    def index(self, points: np.ndarray) -> np.ndarray:
        """Integer cell indices [..., d] of world points [..., d], clipped into the grid."""
        idx = np.floor((np.asarray(points, dtype=float) - self.origin) / self.res).astype(np.int64)
        np.maximum(idx, 0, out=idx)
        return np.minimum(idx, self._last, out=idx)

    def flat_index(self, points: np.ndarray) -> np.ndarray:
        """C-order flat indices [...] into ``cells`` of the cells holding world points [..., d] (clipped, as index)."""
        return self.index(points) @ self._strides

    def cell_center(self, idx: np.ndarray) -> np.ndarray:
        """World centres [..., d] of cells with indices [..., d]."""
        return self.origin + (np.asarray(idx) + 0.5) * self.res

    def value_at(self, points: np.ndarray) -> np.ndarray:
        """Cell values at world points [..., d] (UNKNOWN=-1, FREE=0, OCCUPIED=1)."""
        idx = self.index(points)
        return self.cells[tuple(np.moveaxis(idx, -1, 0))]

    def mark_free(self, points: np.ndarray) -> None:
        """Mark the cells holding world points [..., d] FREE, except cells already OCCUPIED."""
        self.mark_free_cells(self.flat_index(np.asarray(points).reshape(-1, self.dims)))

    def mark_free_cells(self, flat) -> None:
        """Mark the cells with C-order flat indices ``flat`` [K] (0 <= flat < cells.size) FREE, except OCCUPIED ones."""
        flat = np.asarray(flat).reshape(-1)
        view = self.cells.reshape(-1)
        view[flat] = np.maximum(view[flat], FREE)          # UNKNOWN (-1) -> FREE (0); OCCUPIED (1) stays

    def mark_occupied(self, points: np.ndarray) -> None:
        """Mark the cells holding world points [..., d] OCCUPIED."""
        self.mark_occupied_cells(self.flat_index(np.asarray(points).reshape(-1, self.dims)))

    def mark_occupied_cells(self, flat) -> None:
        """Mark the cells with C-order flat indices ``flat`` [K] (0 <= flat < cells.size) OCCUPIED.

        ``version`` is incremented once if any of them was not OCCUPIED before.
        """
        flat = np.asarray(flat).reshape(-1)
        view = self.cells.reshape(-1)
        if flat.shape[0] and np.any(view[flat] != OCCUPIED):
            view[flat] = OCCUPIED
            self.version += 1

    def discovered(self) -> int:
        """Number of cells that are no longer UNKNOWN."""
        return int(np.count_nonzero(self.cells != UNKNOWN))

    def _occupied(self) -> tuple[np.ndarray, dict]:
        """The OCCUPIED mask [shape] and the masks cached from it; the cache is dropped when the OCCUPIED cells
        differ from those it was built from (any write to ``cells``; compared cell by cell in compiled code)."""
        built_from, masks = self._near_cache
        if (built_from is None or built_from.shape != self.cells.shape
                or not _occupied_equals(self.cells.reshape(-1), built_from.reshape(-1))):
            self._near_cache = (self.cells == OCCUPIED, {})
        return self._near_cache

    def near_occupied(self, h: int) -> np.ndarray | None:
        """Bool mask [shape]: cells within Chebyshev index distance ``h`` of an OCCUPIED cell (None if no cell is
        OCCUPIED). Rebuilt when the OCCUPIED cells differ from those it was built from (any write to ``cells``)."""
        return self._near(h, *self._occupied())

    @staticmethod
    def _near(h: int, occ: np.ndarray, masks: dict) -> np.ndarray | None:
        mask = masks.get(h)
        if mask is None:
            if not occ.any():
                return None
            shape = np.asarray(occ.shape, dtype=np.int64)
            mask = _dilate(np.ascontiguousarray(occ).reshape(-1), shape, int(h)).reshape(occ.shape)
            masks[h] = mask
        return mask

    @staticmethod
    def _near_reference(h: int, occ: np.ndarray) -> np.ndarray:
        """_near's mask by shift-ORs in numpy: the reference twin of the compiled _dilate (the same mask)."""
        mask = occ.copy()
        for axis in range(mask.ndim):          # a separable square dilation: shift-OR along each axis
            src = mask.copy()
            n = mask.shape[axis]
            for k in range(1, min(h, n - 1) + 1):
                lo = [slice(None)] * mask.ndim
                hi = [slice(None)] * mask.ndim
                lo[axis], hi[axis] = slice(0, n - k), slice(k, n)
                mask[tuple(lo)] |= src[tuple(hi)]
                mask[tuple(hi)] |= src[tuple(lo)]
        return mask

    def clearance(self, points: np.ndarray, max_dist: float) -> np.ndarray:
        """Distance (m) from each world point [K, d] to the nearest OCCUPIED cell square/cube, capped at max_dist.

        Exact point-to-box distance over the cells within max_dist; 0 inside an occupied cell. Points whose cell is
        more than ceil(max_dist / res) cells from every OCCUPIED cell (near_occupied) get max_dist without the
        search: every box is at least that far from them (a point outside the grid is farther from each box than
        the border cell it is clipped to).
        """
        pts = np.asarray(points, dtype=float).reshape(-1, self.dims)
        out = np.full(pts.shape[0], float(max_dist))
        if pts.shape[0] == 0:
            return out
        h = max(int(np.ceil(max_dist / self.res)), 0)
        occupied = self._occupied()
        near = self._near(h, *occupied)
        if near is None:
            return out
        base = self.index(pts)                                   # [K, d]
        close = near[tuple(base.T)]
        if not close.all():
            rows = np.flatnonzero(close)
            if rows.shape[0] == 0:
                return out
            out[rows] = self._clearance_search(pts[rows], base[rows], max_dist, occupied)
            return out
        return self._clearance_search(pts, base, max_dist, occupied)

    def _clearance_search(self, pts: np.ndarray, base: np.ndarray, max_dist: float, occupied=None) -> np.ndarray:
        """clearance() by searching the OCCUPIED cells near each point's cell (base: its indices [K, d]): one
        gather of the cells at the offsets whose box can lie within max_dist of a point in the base cell
        (_offsets), then exact point-to-box distances for the OCCUPIED ones only. ``occupied``: _occupied()'s
        result when the caller has it."""
        out = np.full(pts.shape[0], float(max_dist))
        reach = int(np.ceil(max_dist / self.res)) + 1
        idx_off, flat_off, strides = self._offsets(max_dist, reach)
        padded = self._padded(reach, *(self._occupied() if occupied is None else occupied))
        centre = (base + reach) @ strides                                              # [K] in the padded array
        rows, cols = np.nonzero(padded[centre[:, None] + flat_off[None, :]])
        if rows.shape[0] == 0:
            return out
        cmin = self.origin + (base[rows] + idx_off[cols]) * self.res
        p = pts[rows]
        delta = np.maximum(np.maximum(cmin - p, p - (cmin + self.res)), 0.0)
        np.minimum.at(out, rows, np.sqrt(np.sum(delta * delta, axis=-1)))
        return out

    @staticmethod
    def _padded(reach: int, occ: np.ndarray, masks: dict) -> np.ndarray:
        """The OCCUPIED mask padded by ``reach`` False cells on every side, flat (offsets from any cell stay inside),
        cached with the masks built from ``occ``."""
        padded = masks.get(("padded", reach))
        if padded is None:
            out = np.zeros(tuple(n + 2 * reach for n in occ.shape), dtype=bool)
            out[(slice(reach, -reach),) * occ.ndim] = occ
            padded = masks[("padded", reach)] = out.reshape(-1)
        return padded

    def _offsets(self, max_dist: float, reach: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cell offsets [W, d] within Chebyshev distance ``reach`` whose box can come within max_dist of a point in
        the centre cell (per axis the gap is at least (|o| - 1) res; 1% of a cell of slack for points that floor()
        put in a neighbouring cell), their flat offsets [W] in the OCCUPIED mask padded by ``reach``, and
        that array's C-order strides [d]. Boxes beyond max_dist cannot change a clearance capped at max_dist."""
        key = (float(max_dist), reach)
        hit = self._offset_cache.get(key)
        if hit is None:
            w = np.array(list(itertools.product(range(-reach, reach + 1), repeat=self.dims)), dtype=np.int64)
            gap = np.maximum(np.abs(w) - 1, 0) * self.res
            w = w[np.sqrt(np.sum(gap * gap, axis=1)) <= max_dist + 0.01 * self.res]
            padded = np.asarray(self.shape, dtype=np.int64) + 2 * reach
            strides = np.ascontiguousarray(np.cumprod(np.concatenate([padded[1:], [1]])[::-1])[::-1])
            hit = (w, w @ strides, strides)
            self._offset_cache[key] = hit
        return hit

    def collides(self, points: np.ndarray, radius: float) -> np.ndarray:
        """True for each world point [K, d] whose ball of ``radius`` (m) overlaps an OCCUPIED cell (thesis A-3):
        clearance(points, radius + res) < radius, decided in compiled code (_collides) over the same cells, with
        the same distance arithmetic, stopping at the first cell closer than radius."""
        pts = np.asarray(points, dtype=float).reshape(-1, self.dims)
        max_dist = radius + self.res
        if not max_dist > radius:
            return self.clearance(pts, max_dist) < radius
        query = self.collision_query(radius)
        if query is None or pts.shape[0] == 0:
            return np.zeros(pts.shape[0], dtype=bool)        # no OCCUPIED cell: clearance() is max_dist > radius
        return _collides(pts, *query)

    def collision_query(self, radius: float) -> tuple | None:
        """The arguments after the points of the compiled query _collides(points, *args) that collides() makes for
        a ball of ``radius`` (m; radius + res > radius), or None when no cell is OCCUPIED (nothing collides). For
        compiled callers that check many point sets against one grid state."""
        occ, masks = self._occupied()
        key = ("query", radius)
        if key not in masks:
            max_dist = radius + self.res
            h = max(int(np.ceil(max_dist / self.res)), 0)
            near = self._near(h, occ, masks)
            if near is None:
                masks[key] = None
            else:
                reach = int(np.ceil(max_dist / self.res)) + 1
                idx_off, flat_off, strides = self._offsets(max_dist, reach)
                masks[key] = (self.origin, self.res, self._last, near.reshape(-1), self._strides,
                              self._padded(reach, occ, masks), idx_off, flat_off, strides, reach, float(radius))
        return masks[key]

    def copy(self) -> "OccupancyGrid":
        """A deep copy."""
        g = OccupancyGrid.__new__(OccupancyGrid)
        g.__dict__.update(self.__dict__)
        g.cells = self.cells.copy()
        g._offset_cache = {}
        g._near_cache = (None, {})
        return g


@njit(cache=True, nogil=True)
def _collides(pts, origin, res, last, near, cell_strides, padded, idx_off, flat_off, pad_strides, reach, radius):
    """OccupancyGrid.collides for points [K, d]: _point_collides of each."""
    n_pts, d = pts.shape
    out = np.zeros(n_pts, dtype=np.bool_)
    base = np.empty(d, dtype=np.int64)
    for i in range(n_pts):
        out[i] = _point_collides(pts[i], base, origin, res, last, near, cell_strides, padded, idx_off, flat_off,
                                 pad_strides, reach, radius)
    return out


@njit(cache=True, nogil=True)
def _point_collides(pt, base, origin, res, last, near, cell_strides, padded, idx_off, flat_off, pad_strides, reach,
                    radius):
    """Does the ball of ``radius`` at point pt [d] meet an OCCUPIED cell? Clear if its cell (clipped into the grid)
    is not near an OCCUPIED cell; otherwise True if the box of an OCCUPIED cell at one of the offsets idx_off [W, d]
    (flat offsets flat_off in the mask ``padded`` by reach cells, strides pad_strides) is closer than radius. The box
    distance is _clearance_search's: per axis max(cmin - p, p - (cmin + res), 0), squares summed axis by axis.
    base: scratch [d] (int64)."""
    d = pt.shape[0]
    cell = 0
    centre = 0
    for j in range(d):
        b = np.int64(np.floor((pt[j] - origin[j]) / res))
        b = min(max(b, 0), last[j])
        base[j] = b
        cell += b * cell_strides[j]
        centre += (b + reach) * pad_strides[j]
    if not near[cell]:
        return False
    for w in range(flat_off.shape[0]):
        if not padded[centre + flat_off[w]]:
            continue
        dist2 = 0.0
        for j in range(d):
            cmin = origin[j] + (base[j] + idx_off[w, j]) * res
            p = pt[j]
            delta = max(max(cmin - p, p - (cmin + res)), 0.0)
            dist2 += delta * delta
        if np.sqrt(dist2) < radius:
            return True
    return False


@njit(cache=True, nogil=True)
def _occupied_equals(cells, occ):
    """True if the OCCUPIED cells of ``cells`` [n] (int8) are exactly the True entries of ``occ`` [n]."""
    for i in range(cells.shape[0]):
        if (cells[i] == OCCUPIED) != occ[i]:
            return False
    return True


@njit(cache=True, nogil=True)
def _dilate(occ, shape, h):
    """The cells [flat, C order, of ``shape``] within Chebyshev index distance h of a True cell of ``occ``: per axis
    in turn, every True cell marks its neighbours up to h cells away along that axis (a separable square
    dilation; OccupancyGrid._near_reference is its reference twin)."""
    mask = occ.copy()
    nd = shape.shape[0]
    stride = 1
    for axis in range(nd - 1, -1, -1):
        n = shape[axis]
        reach = min(h, n - 1)
        src = mask.copy()
        for i in range(src.shape[0]):
            if not src[i]:
                continue
            c = (i // stride) % n
            for k in range(1, reach + 1):
                if c - k >= 0:
                    mask[i - k * stride] = True
                if c + k < n:
                    mask[i + k * stride] = True
        stride *= n
    return mask
