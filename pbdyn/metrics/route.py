"""Task-level difficulty along the static-free route: the shortest path from start to goal around static geometry,
and the task metrics of pbdyn.metrics.task measured along it instead of along the straight segment.

static_route: the shortest path that keeps the MAV (radius r) clear of static geometry (generated pillars and boxes;
imported worlds' still bodies at t = 0, in 2D their cross-section in the flight plane) and inside the arena box
[0, L] with r to spare. Moving obstacles are ignored, even ones whose speed is 0. Grid rule:

1. Nodes at k * cell on every axis; a node is free where its clearance -- the distance to the nearest static
   surface or arena wall (exact signed distances) -- is >= r.
2. A* on the free nodes, 8-connected in 2D and 26-connected in 3D, edge cost = its Euclidean length, heuristic
   the grid metric to the goal (consistent, so the grid path is a shortest grid path). Start and goal (which must
   have clearance >= r) join the grid at the nearest free node of the 4^d around them whose segment passes the
   test of rule 3, else at the nearest free one; none free, or different free components: no route.
3. Any-angle refinement: string pulling -- from each kept vertex, the farthest later vertex whose straight segment
   passes the test: the clearance, read by multilinear interpolation of the node values at points every cell / 4 m,
   is >= r (consecutive vertices are always joined) -- then rounds of string pulling on the polyline with points
   added around each bend (cell * 2^m from it, m >= -3), alternately from either end, until the length stops
   dropping; collinear vertices are dropped.

Error bound (d = 2, 3; L*(rho): the true shortest path length for a MAV of radius rho):
    L*(r - delta) <= length <= c_d (L*(r + cell sqrt(d) / 2) + sqrt(d) cell),
delta = cell sqrt(d) / 2 + cell / 8. Lower: interpolating a 1-Lipschitz distance errs by at most cell sqrt(d) / 2
and a segment dips at most half the sampling step between its samples, so segments that passed the test keep a true
clearance >= r - delta (edges between neighbouring free nodes: >= r - cell sqrt(d) / 2); the route is feasible for
a MAV of radius r - delta. Upper: string pulling only shortens the grid path, and a shortest grid path is at most
c_d = max grid metric / Euclidean distance (2D: sec 22.5 deg = 1.0824; 3D: 1.1281) times longer than a continuous
path whose nodes nearby are all free, plus the joins at its ends. Measured at cell = 0.5 m (tests/test_route.py):
within 0.15 m of analytic shortest paths around a wall's gap (2D) and over a wall (3D), and a true clearance
>= r - 0.04 m on the bundled structured and imported worlds.

Task metrics (thesis ch. 3), start -> goal from ``start_time``:
- route_detour (1, >= 1; higher = harder): route length / straight distance.
- route_survivability (s; higher = easier): eq. 3-6 on route_points -- samples every ``spacing`` m along the route
  and shifted +-``half_width`` m across it (pbdyn.metrics.task.corridor_points' rule, following the route), kept
  where the MAV stays in the arena and off static geometry -- with corridor_survivability's kernel and backend.
- route_flux (1/s; higher = harder): corridor_flux's closed form (pbdyn.metrics.task.points_flux) on those samples.
Without a route they are NaN (no samples: NaN, 0). route_metrics: their means over a map's ordered start/goal pairs
(per_sample = per task). The route and its samples do not depend on the task's direction: the search runs from the
lexicographically smaller end, so the task goal -> start has the same route reversed.
"""

from __future__ import annotations

import heapq
import itertools
import math
import time as _time
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from pbdyn import limits
from pbdyn.errors import ConfigError
from pbdyn.jit import njit
from pbdyn.metrics.backends import kernel
from pbdyn.metrics.baselines import equivalent_radii
from pbdyn.metrics.result import MetricResult
from pbdyn.metrics.sampling import plane_points
from pbdyn.metrics.survivability import jsonable, positive, split_static, summary
from pbdyn.metrics.task import points_flux
from pbdyn.metrics.traversability import default_starts

GRID_FACTOR = {2: 1.0823922002923938, 3: 1.1280928107595822}
"""c_d: the largest ratio of the 8- (2D) / 26-connected (3D) grid metric to the Euclidean distance."""
STATUSES = ("ok", "start_blocked", "goal_blocked", "no_route")
_EPS = 1e-9


@dataclass(frozen=True)
class Route:
    """A static-free route (module doc). waypoints [K, d] (m; start first, goal last; [0, d] without a route),
    length (m; NaN without a route), straight (m), detour = length / straight (1; 1 for start = goal), exists,
    status: "ok", "start_blocked" / "goal_blocked" (the MAV there overlaps static geometry or leaves the arena),
    "no_route" (no free path joins them)."""

    waypoints: np.ndarray
    length: float
    straight: float
    detour: float
    exists: bool
    status: str


@dataclass(frozen=True)
class RouteGrid:
    """The free-node grid of one rollout, MAV radius and cell (build with route_grid; reuse it for many tasks).
    clearance: node clearances (m; shape = nodes per axis; capped at mav_radius + 2 cell sqrt(d)), free: clearance
    >= mav_radius, component: labels of the 8/26-connected free components (0 = blocked)."""

    mav_radius: float
    cell: float
    clearance: np.ndarray
    free: np.ndarray
    component: np.ndarray
    arena_size: np.ndarray


def static_clearance(rollout, points, cap: float = math.inf) -> np.ndarray:
    """min(distance to the nearest static surface or arena wall, ``cap``) (m) at points [n, d] (negative inside a
    body or outside the arena): generated static bodies and imported still bodies at t = 0; a still body is queried
    only at points within ``cap`` of its bounding box (the others are farther than ``cap`` from it)."""
    pts = np.asarray(points, dtype=float).reshape(-1, rollout.dims)
    size = np.asarray(rollout.arena_size, dtype=float)
    out = np.minimum(np.min(np.minimum(pts, size[None, :] - pts), axis=1), cap)
    for body in rollout.static:
        out = np.minimum(out, body.footprint_distance(pts))
    bodies = getattr(rollout, "bodies", None)
    if bodies is None or pts.shape[0] == 0:
        return out
    field = bodies.field()
    q = plane_points(rollout, pts)
    for b in np.flatnonzero(~bodies.moving).tolist():
        lo, hi = field.world_bounds(b, 0)
        near = np.flatnonzero(np.all((q >= lo[None, :] - cap) & (q <= hi[None, :] + cap), axis=1))
        if near.size:
            out[near] = np.minimum(out[near], field.body_distance(b, q[near], 0))
    return out


def route_grid(rollout, *, mav_radius: float = 1.0, cell: float = 0.5) -> RouteGrid:
    """The free-node grid (module doc, rule 1) of ``rollout`` for a MAV of ``mav_radius`` m on nodes every ``cell``
    m; ConfigError naming "cell" above limits.MAX_METRIC_SAMPLES nodes."""
    mav_radius = positive("mav_radius", mav_radius)
    cell = positive("cell", cell)
    size = np.asarray(rollout.arena_size, dtype=float)
    shape = tuple(int(math.floor(L / cell + _EPS)) + 1 for L in size)
    limits.check_limit("cell", "route grid nodes (the arena's extents / cell, per axis)",
                       float(np.prod([float(n) for n in shape])), limits.MAX_METRIC_SAMPLES, cell)
    axes = [np.arange(n) * cell for n in shape]
    nodes = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(shape))
    # rules 1 and 3 only compare values within a cell diagonal of mav_radius (the field is 1-Lipschitz)
    cap = mav_radius + 2.0 * cell * math.sqrt(len(shape))
    clearance = static_clearance(rollout, nodes, cap).reshape(shape)
    free = clearance >= mav_radius - _EPS
    component, _ = ndimage.label(free, structure=np.ones((3,) * len(shape), dtype=bool))
    for a in (clearance, free, component):
        a.setflags(write=False)
    return RouteGrid(mav_radius, cell, clearance, free, component, size)


# ----------------------------------------------------------------------------------------------------------------
# grid search
# ----------------------------------------------------------------------------------------------------------------
def neighbour_offsets(dims: int) -> np.ndarray:
    """The 8 (2D) / 26 (3D) integer neighbour steps [m, d], in itertools.product order."""
    return np.array([s for s in itertools.product((-1, 0, 1), repeat=dims) if any(s)], dtype=np.int64)


@njit(cache=True, nogil=True)
def _grid_metric(here, tgt, dims):
    """Grid distance (cells) between integer nodes here [d] and tgt [d]: (a - b) + sqrt 2 (b - c) + sqrt 3 c for
    the sorted absolute differences a >= b >= c (c = 0 in 2D)."""
    a = abs(here[0] - tgt[0])
    b = abs(here[1] - tgt[1])
    c = abs(here[2] - tgt[2]) if dims == 3 else 0
    if a < b:
        a, b = b, a
    if b < c:
        b, c = c, b
    if a < b:
        a, b = b, a
    return (a - b) + math.sqrt(2.0) * (b - c) + math.sqrt(3.0) * c


@njit(cache=True, nogil=True)
def _astar(free, shape, steps, source, target):
    """A* over the padded flat grid ``free`` (bool, a False border one node wide; ``shape`` the padded shape) from
    flat node ``source`` to ``target`` with neighbour steps [m, d]; returns (cost in cells (inf if unreachable),
    predecessors [M] (-1: none)). Heap keys (f, -g, node): deterministic, deeper nodes first on ties."""
    dims = shape.shape[0]
    strides = np.ones(dims, dtype=np.int64)
    for a in range(dims - 2, -1, -1):
        strides[a] = strides[a + 1] * shape[a + 1]
    m = steps.shape[0]
    offs = np.zeros(m, dtype=np.int64)
    costs = np.zeros(m)
    for k in range(m):
        sq = 0.0
        for a in range(dims):
            offs[k] += steps[k, a] * strides[a]
            sq += steps[k, a] * steps[k, a]
        costs[k] = math.sqrt(sq)
    tgt = np.zeros(dims, dtype=np.int64)
    rem = target
    for a in range(dims):
        tgt[a] = rem // strides[a]
        rem -= tgt[a] * strides[a]
    n = free.shape[0]
    g = np.full(n, np.inf)
    pred = np.full(n, -1, dtype=np.int64)
    closed = np.zeros(n, dtype=np.bool_)
    here = np.zeros(dims, dtype=np.int64)
    g[source] = 0.0
    heap = [(0.0, 0.0, source)]
    while len(heap) > 0:
        _, neg_g, u = heapq.heappop(heap)
        if closed[u]:
            continue
        closed[u] = True
        if u == target:
            break
        gu = -neg_g
        for k in range(m):
            v = u + offs[k]
            if not free[v] or closed[v]:
                continue
            gv = gu + costs[k]
            if gv < g[v]:
                g[v] = gv
                pred[v] = u
                rem = v
                for a in range(dims):
                    here[a] = rem // strides[a]
                    rem -= here[a] * strides[a]
                heapq.heappush(heap, (gv + _grid_metric(here, tgt, dims), -gv, v))
    return g[target], pred


def grid_path(grid: RouteGrid, source: tuple, target: tuple) -> tuple[float, np.ndarray]:
    """(length (m), node indices [K, d]) of a shortest 8/26-connected grid path between two free nodes (index
    tuples); (inf, [0, d]) when none."""
    shape = np.array(grid.free.shape, dtype=np.int64)
    d = shape.shape[0]
    padded = np.pad(grid.free, 1, constant_values=False)
    pshape = np.array(padded.shape, dtype=np.int64)
    flat = lambda idx: int(np.ravel_multi_index(tuple(int(i) + 1 for i in idx), padded.shape))  # noqa: E731
    cost, pred = _astar(padded.ravel(), pshape, neighbour_offsets(d), flat(source), flat(target))
    if not np.isfinite(cost):
        return float("inf"), np.zeros((0, d), dtype=np.int64)
    chain = [flat(target)]
    while chain[-1] != flat(source):
        chain.append(int(pred[chain[-1]]))
    idx = np.stack(np.unravel_index(np.array(chain[::-1]), padded.shape), axis=1) - 1
    return float(cost) * grid.cell, idx


# ----------------------------------------------------------------------------------------------------------------
# refinement
# ----------------------------------------------------------------------------------------------------------------
def interpolated_clearance(grid: RouteGrid, points: np.ndarray) -> np.ndarray:
    """Multilinear interpolation (m) of the node clearances at points [n, d] (m)."""
    coords = np.asarray(points, dtype=float).T / grid.cell
    return ndimage.map_coordinates(np.asarray(grid.clearance), coords, order=1, mode="nearest")


def _visible(grid: RouteGrid, p: np.ndarray, qs: np.ndarray) -> np.ndarray:
    """True for each segment p -> qs[j] whose interpolated clearance is >= mav_radius at points every cell / 4."""
    h = grid.cell / 4.0
    lengths = np.linalg.norm(qs - p[None, :], axis=1)
    counts = np.ceil(lengths / h).astype(np.int64) + 1
    seg = np.repeat(np.arange(qs.shape[0]), counts)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    t = (np.arange(seg.shape[0]) - first[seg]) / np.maximum(counts[seg] - 1, 1)
    pts = p[None, :] + t[:, None] * (qs[seg] - p[None, :])
    lowest = np.minimum.reduceat(interpolated_clearance(grid, pts), first)
    return lowest >= grid.mav_radius - _EPS


def pull_string(grid: RouteGrid, points: np.ndarray) -> np.ndarray:
    """Any-angle refinement (module doc, rule 3) of a polyline [K, d] (m): kept vertices [K', d]."""
    keep = [0]
    i = 0
    while i < points.shape[0] - 1:
        best = i + 1
        if i + 2 < points.shape[0]:
            ok = np.flatnonzero(_visible(grid, points[i], points[i + 2:]))
            if ok.size:
                best = i + 2 + int(ok[-1])
        keep.append(best)
        i = best
    return points[keep]


def _polyline_length(points: np.ndarray) -> float:
    return float(np.sum(np.linalg.norm(np.diff(points, axis=0), axis=1)))


def _densify_bends(points: np.ndarray, cell: float) -> np.ndarray:
    """The polyline [K, d] with points added on both segments at each interior vertex, at cell * 2^m (m >= -3) from
    the vertex, up to half the segment."""
    out = [points[:1]]
    for k in range(1, points.shape[0]):
        a, b = points[k - 1], points[k]
        seg = b - a
        n = float(np.linalg.norm(seg))
        ds = []
        if n > 0:
            steps = cell * 2.0 ** np.arange(-3, max(-2, int(math.ceil(math.log2(max(n, cell) / cell))) + 1))
            steps = steps[steps < 0.5 * n]
            if k > 1:
                ds.extend(steps.tolist())                                # after the vertex a
            if k < points.shape[0] - 1:
                ds.extend((n - steps).tolist())                          # before the vertex b
        ts = np.unique(np.array(ds, dtype=float)) / n if ds else np.zeros(0)
        out.append(a[None, :] + ts[:, None] * seg[None, :])
        out.append(b[None, :])
    return np.concatenate(out)


def refine(grid: RouteGrid, points: np.ndarray, max_rounds: int = 40) -> np.ndarray:
    """Any-angle refinement (module doc, rule 3) of a grid path [K, d] (m): string pulling, then rounds of pulling
    the polyline densified around its bends, alternately from either end, while the length drops by > 1e-6 m."""
    best = pull_string(grid, points)
    length = _polyline_length(best)
    stale = 0
    for i in range(max_rounds):
        dense = _densify_bends(best, grid.cell)
        new = pull_string(grid, dense[::-1])[::-1] if i % 2 == 0 else pull_string(grid, dense)
        new_length = _polyline_length(new)
        if new_length < length - 1e-6:
            best, length, stale = new, new_length, 0
        else:
            stale += 1
            if stale == 2:
                break
    return _drop_collinear(best)


def _drop_collinear(points: np.ndarray) -> np.ndarray:
    """The polyline without interior vertices that lie on the segment joining their neighbours (to 1e-9 m)."""
    keep = [0]
    for k in range(1, points.shape[0] - 1):
        a, v, b = points[keep[-1]], points[k], points[k + 1]
        ab = b - a
        t = float(np.dot(v - a, ab) / max(float(np.dot(ab, ab)), 1e-300))
        if not (0.0 <= t <= 1.0 and np.linalg.norm(a + t * ab - v) <= 1e-9):
            keep.append(k)
    keep.append(points.shape[0] - 1)
    return points[keep]


# ----------------------------------------------------------------------------------------------------------------
# the route
# ----------------------------------------------------------------------------------------------------------------
def _check_point(grid: RouteGrid, p, name: str) -> np.ndarray:
    q = np.asarray(p, dtype=float).reshape(-1)
    if q.shape[0] != grid.arena_size.shape[0] or not np.all(np.isfinite(q)):
        raise ConfigError(name, f"must be {grid.arena_size.shape[0]} finite coordinates (m)", jsonable(q))
    return q


def _entry_node(grid: RouteGrid, p: np.ndarray):
    """Where ``p`` joins the grid: among the free nodes of the 4^d block around its cell, the nearest one whose
    segment from ``p`` passes rule 3's test, else the nearest one (ties: C order); None if none is free."""
    base = np.floor(p / grid.cell).astype(np.int64) - 1
    block = base[None, :] + _block(p.shape[0])
    block = block[np.all((block >= 0) & (block < np.array(grid.free.shape)), axis=1)]
    block = block[grid.free[tuple(block.T)]] if block.shape[0] else block
    if block.shape[0] == 0:
        return None
    order = np.argsort(np.linalg.norm(block * grid.cell - p[None, :], axis=1), kind="stable")
    block = block[order]
    seen = np.flatnonzero(_visible(grid, p, block * grid.cell))
    return tuple(int(x) for x in block[int(seen[0]) if seen.size else 0])


def _block(dims: int) -> np.ndarray:
    """The integer offsets {0, 1, 2, 3}^d [4^d, d], in C order."""
    return np.array(list(itertools.product(range(4), repeat=dims)), dtype=np.int64)


def static_route(rollout, start, goal, *, mav_radius: float = 1.0, cell: float = 0.5,
                 grid: RouteGrid | None = None) -> Route:
    """The shortest static-free route start -> goal (m; module doc: grid rule and error bound) for a MAV of
    ``mav_radius`` m on nodes every ``cell`` m; ``grid``: a route_grid of the same rollout, radius and cell to reuse.
    Never raises for blocked or disconnected tasks: Route.status says why there is none."""
    if grid is None:
        grid = route_grid(rollout, mav_radius=mav_radius, cell=cell)
    elif (grid.mav_radius, grid.cell) != (float(mav_radius), float(cell)):
        raise ConfigError("grid", f"was built for mav_radius {grid.mav_radius:g} m and cell {grid.cell:g} m",
                          [float(mav_radius), float(cell)])
    s = _check_point(grid, start, "start")
    g = _check_point(grid, goal, "goal")
    straight = float(np.linalg.norm(g - s))
    d = s.shape[0]
    if tuple(g) < tuple(s):
        r = static_route(rollout, g, s, mav_radius=mav_radius, cell=cell, grid=grid)
        status = {"start_blocked": "goal_blocked", "goal_blocked": "start_blocked"}.get(r.status, r.status)
        back = r.waypoints[::-1].copy()
        back.setflags(write=False)
        return Route(back, r.length, r.straight, r.detour, r.exists, status)

    def none(status: str) -> Route:
        empty = np.zeros((0, d))
        empty.setflags(write=False)
        return Route(empty, float("nan"), straight, float("nan"), False, status)

    clear = static_clearance(rollout, np.stack([s, g]))
    if clear[0] < grid.mav_radius - _EPS:
        return none("start_blocked")
    if clear[1] < grid.mav_radius - _EPS:
        return none("goal_blocked")
    if straight == 0.0:
        pts = np.stack([s, g])
        pts.setflags(write=False)
        return Route(pts, 0.0, 0.0, 1.0, True, "ok")
    a, b = _entry_node(grid, s), _entry_node(grid, g)
    if a is None or b is None or grid.component[a] != grid.component[b]:
        return none("no_route")
    if _visible(grid, s, g[None, :])[0]:
        pts = np.stack([s, g])
    else:
        _, idx = grid_path(grid, a, b)
        pts = refine(grid, np.concatenate([s[None, :], idx * grid.cell, g[None, :]]))
    pts = pts[np.concatenate([[True], np.any(np.diff(pts, axis=0) != 0.0, axis=1)])]
    if pts.shape[0] == 1:
        pts = np.stack([s, g])
    length = float(np.sum(np.linalg.norm(np.diff(pts, axis=0), axis=1)))
    pts.setflags(write=False)
    return Route(pts, length, straight, max(1.0, length / straight), True, "ok")


def route_points(waypoints, arena_size, *, spacing: float = 3.0, half_width: float = 3.0,
                 mav_radius: float = 1.0) -> np.ndarray:
    """The route's samples [n, d] (m), before static geometry is removed: ceil(length / spacing) + 1 points evenly
    spaced along the polyline ``waypoints`` [K, d] (both ends included), and the same points shifted ``half_width``
    m to each side of the segment they lie on (2D: +-the left normal; 3D: +-two unit vectors across it), kept where
    the MAV stays inside the arena -- corridor_points' rule (identical for a two-point route). The polyline is taken
    from its lexicographically smaller end, so a reversed route gives the same samples."""
    w = np.asarray(waypoints, dtype=float)
    d = w.shape[1]
    if w.shape[0] == 0:
        return np.zeros((0, d))
    if tuple(w[-1]) < tuple(w[0]):
        w = w[::-1]
    spacing = positive("spacing", spacing)
    seg = np.diff(w, axis=0)
    lens = np.linalg.norm(seg, axis=1)
    w, seg, lens = np.concatenate([w[:1], w[1:][lens > 0]]), seg[lens > 0], lens[lens > 0]
    total = float(lens.sum())
    n_along = max(1, int(math.ceil(total / spacing))) + 1
    u = np.linspace(0.0, 1.0, n_along)
    if seg.shape[0] == 0:
        line, dirs = np.repeat(w[:1], n_along, axis=0), np.tile(np.eye(d)[0], (n_along, 1))
    else:
        c = np.concatenate([[0.0], np.cumsum(lens)]) / total
        c[-1] = 1.0
        k = np.clip(np.searchsorted(c, u, side="right") - 1, 0, seg.shape[0] - 1)
        frac = (u - c[k]) / (c[k + 1] - c[k])
        line = w[k] + frac[:, None] * seg[k]
        dirs = seg[k] / lens[k][:, None]
    if d == 2:
        across = [np.stack([-dirs[:, 1], dirs[:, 0]], axis=1)]
    else:
        ref = np.where(np.abs(dirs[:, 2:3]) < 0.9, np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 0.0, 0.0]]))
        e1 = np.cross(dirs, ref)
        e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
        across = [e1, np.cross(dirs, e1)]
    pts = [line] + [line + sign * half_width * e for e in across for sign in (1.0, -1.0)] \
        if half_width > 0 else [line]
    pts = np.concatenate(pts, axis=0)
    size = np.asarray(arena_size, dtype=float)
    inside = np.all((pts >= mav_radius) & (pts <= size - mav_radius), axis=1)
    return pts[inside]


# ----------------------------------------------------------------------------------------------------------------
# task metrics
# ----------------------------------------------------------------------------------------------------------------
def _route(rollout, start, goal, route, mav_radius, cell) -> Route:
    return route if route is not None else static_route(rollout, start, goal, mav_radius=mav_radius, cell=cell)


def route_detour(rollout, start, goal, *, mav_radius: float = 1.0, cell: float = 0.5,
                 route: Route | None = None) -> float:
    """Route detour (1, >= 1; higher = harder): static route length / straight distance; NaN without a route.
    ``route``: a static_route of this task to reuse."""
    return _route(rollout, start, goal, route, mav_radius, cell).detour


def _samples(rollout, r: Route, spacing, half_width, mav_radius) -> np.ndarray:
    if not r.exists:
        return np.zeros((0, rollout.dims))
    pts = route_points(r.waypoints, rollout.arena_size, spacing=spacing, half_width=half_width,
                       mav_radius=mav_radius)
    return split_static(rollout, pts, mav_radius)[0]


def route_survivability(rollout, start, goal, *, start_time: float = 0.0, mav_radius: float = 1.0,
                        t_max: float = 12.0, spacing: float = 3.0, half_width: float = 3.0,
                        backend: str = "analytic", cell: float = 0.5,
                        route: Route | None = None) -> tuple[float, int]:
    """(route survivability (s; thesis eq. 3-6), number of samples) of the task start -> goal: corridor_survivability
    on route_points of the static route (module doc); (NaN, 0) without a route or samples."""
    find = kernel(backend, "sampled")
    r = _route(rollout, start, goal, route, mav_radius, cell)
    pts = _samples(rollout, r, spacing, half_width, mav_radius)
    if pts.shape[0] == 0:
        return float("nan"), 0
    times = find(rollout, pts, mav_radius=mav_radius, t_max=t_max, start_time=start_time)
    return float(np.mean(times)), int(pts.shape[0])


def route_flux(rollout, start, goal, *, start_time: float = 0.0, mav_radius: float = 1.0, horizon: float = 12.0,
               spacing: float = 3.0, half_width: float = 3.0, cell: float = 0.5, radii: np.ndarray | None = None,
               route: Route | None = None) -> tuple[float, int]:
    """(route flux (1/s), number of samples) of the task start -> goal: corridor_flux's closed form on route_points
    of the static route (module doc); (NaN, 0) without a route or samples. ``radii`` as in corridor_flux."""
    horizon = positive("horizon", horizon)
    r = _route(rollout, start, goal, route, mav_radius, cell)
    pts = _samples(rollout, r, spacing, half_width, mav_radius)
    if pts.shape[0] == 0:
        return float("nan"), 0
    return points_flux(rollout, pts, start_time=start_time, mav_radius=mav_radius, horizon=horizon,
                       radii=radii), int(pts.shape[0])


def _pairs(rollout, starts, pairs) -> tuple[np.ndarray, list[tuple[int, int]]]:
    d = rollout.dims
    pts = default_starts(rollout.arena_size) if starts is None else np.asarray(starts, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != d:
        raise ConfigError("starts", f"must be an array [n, {d}]", jsonable(pts))
    n = pts.shape[0]
    if pairs is None:
        out = [(i, j) for i in range(n) for j in range(n) if i != j]
    else:
        out = [tuple(int(x) for x in p) for p in pairs]
        if any(len(p) != 2 or not all(0 <= x < n for x in p) for p in out):
            raise ConfigError("pairs", f"must be (start, goal) index pairs into the {n} starts", jsonable(pairs))
    return pts, out


def route_metrics(rollout, *, starts=None, pairs=None, start_time: float = 0.0, mav_radius: float = 1.0,
                  cell: float = 0.5, t_max: float = 12.0, spacing: float = 3.0, half_width: float = 3.0,
                  backend: str = "analytic") -> dict[str, MetricResult]:
    """route_detour (1), route_survivability (s) and route_flux (1/s, over ``t_max`` s) of a map: their means over
    the tasks ``pairs`` (ordered (start, goal) indices into ``starts`` [n, d] (m); default: the 9 start/goal
    candidates {4, L/2, L - 4}^2 (3D z = L_z / 2) and all their ordered pairs). Each a MetricResult with per_sample
    = the per-task values [P] (NaN for a task without a route or samples: left out of the mean, counted in
    n_excluded); extra: the route lengths (m) and statuses. One route_grid serves every task."""
    t0 = _time.perf_counter()
    mav_radius = positive("mav_radius", mav_radius)
    find = kernel(backend, "sampled")
    pts, tasks = _pairs(rollout, starts, pairs)
    grid = route_grid(rollout, mav_radius=mav_radius, cell=cell)
    canon = [(i, j) if tuple(pts[i]) <= tuple(pts[j]) else (j, i) for i, j in tasks]
    keys = list(dict.fromkeys(canon))
    routes = {k: static_route(rollout, pts[k[0]], pts[k[1]], mav_radius=mav_radius, cell=cell, grid=grid)
              for k in keys}
    radii = equivalent_radii(rollout, start_time) if rollout.n_obstacles else None
    samples = [_samples(rollout, routes[k], spacing, half_width, mav_radius) for k in keys]
    allpts = np.concatenate(samples) if keys else np.zeros((0, rollout.dims))
    times = np.asarray(find(rollout, allpts, mav_radius=mav_radius, t_max=t_max, start_time=start_time),
                       dtype=float) if allpts.shape[0] else np.zeros(0)
    parts = np.split(times, np.cumsum([p.shape[0] for p in samples])[:-1]) if keys else []
    surv = {k: float(np.mean(p)) if p.size else np.nan for k, p in zip(keys, parts)}
    flux = {k: points_flux(rollout, p, start_time=start_time, mav_radius=mav_radius, horizon=t_max, radii=radii)
            if p.shape[0] else np.nan for k, p in zip(keys, samples)}
    per = {"route_detour": np.array([routes[k].detour for k in canon], dtype=float),
           "route_survivability": np.array([surv[k] for k in canon], dtype=float),
           "route_flux": np.array([flux[k] for k in canon], dtype=float)}
    params = {"starts": jsonable(pts), "pairs": [list(t) for t in tasks], "start_time": float(start_time),
              "mav_radius": mav_radius, "cell": grid.cell, "t_max": float(t_max), "spacing": float(spacing),
              "half_width": float(half_width), "backend": backend}
    status = {"start_blocked": "goal_blocked", "goal_blocked": "start_blocked"}
    extra = {"lengths": [routes[k].length if routes[k].exists else None for k in canon],
             "status": [routes[k].status if k == t else status.get(routes[k].status, routes[k].status)
                        for k, t in zip(canon, tasks)]}
    wall = _time.perf_counter() - t0
    out = {}
    for name, values in per.items():
        ok = np.isfinite(values)
        value, err = summary(values[ok])
        values.setflags(write=False)
        out[name] = MetricResult(name, value, params, int(np.count_nonzero(ok)), int(np.count_nonzero(~ok)),
                                 values, err, extra, wall)
    return out
