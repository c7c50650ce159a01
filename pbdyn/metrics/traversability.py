"""Traversability (thesis eq. 3-2) and dynamic traversability (eq. 3-3): how far the MAV can move in a straight
line from sampled starts before it touches something.

Exact mode: d = the distance the MAV centre moves along a unit direction before its disc/ball (radius r_mav)
touches an obstacle (ray vs disc/ball of radius r_i + r_mav; 2D planar, 3D Euclidean), a static body (ray vs its
footprint inflated by r_mav: pillars are discs / infinite vertical cylinders, boxes rounded rectangles / rounded
cuboids, intersected exactly) or a wall (a coordinate reaching r_mav or L - r_mav). Obstacles are a snapshot at
``time``. Imported worlds: the bodies' real shapes (static and moving) instead of discs/balls, the touching
distance found by sphere tracing on their exact signed-distance field (pbdyn.world.shapes; tolerance 1e-4 m).

Grid mode (the thesis' cell walk): cells of ``cell`` m; from the start's cell walk along one of the neighbour
directions to the first blocked cell; d = cells walked x cell (x sqrt 2 diagonally, x sqrt 3 on 3D space
diagonals). Which cells are blocked is the ``marking``:

- ``"centre_inside"`` (default): a cell is blocked if its centre lies inside an obstacle (distance < r_i, no MAV
  inflation) or a static body, or outside the arena.
- ``"program"``: the thesis' own program (docs/thesis-program.md "Metrics as computed for the thesis' tables";
  read from its public code, smoggy-P/gym-Drone2D-ActivePerception). Its ground-truth grid had the arena's walls
  in the outermost ring of cells; the thesis scenarios (scenarios/thesis) model its arena as the 48 m between those
  cells, so here, as with every marking, the walls lie outside the grid. It marked dynamic obstacles in two
  ways. A freshly built map (what its traversability, eq. 3-2, read at t = 0) blocks a cell whose centre is
  inside or on an obstacle's disc. A map stepped forward (what its dynamic traversability, eq. 3-3, read) blocks
  the square of cells within floor(r_i / cell) cells (per axis) of the cell holding the obstacle's centre: one
  cell for r_i < cell, 3 x 3 cells for cell <= r_i < 2 cell. traversability uses the first rule,
  dynamic_traversability the second. (The program also took its dynamic samples one step late, at t + dt; that
  is a choice of ``times``, not of marking, and is not applied.) Static bodies are marked as in
  ``"centre_inside"`` (centre inside or on them); imported worlds' moving bodies are marked by their bounding
  spheres, static ones by their real shapes.
"""

from __future__ import annotations

import itertools
import time as _time

import numpy as np

from pbdyn import limits
from pbdyn.errors import ConfigError
from pbdyn.metrics.result import MetricResult
from pbdyn.metrics.sampling import grid_samples, outside_geometry, plane_points
from pbdyn.metrics.survivability import jsonable, positive, summary
from pbdyn.world.geometry import StaticBody

MODES = ("exact", "grid")
MARKINGS = ("centre_inside", "program")
"""Grid-mode cell marking of the metrics (module doc)."""
CELL_RULES = ("centre_inside", "program_reset", "program_step")
"""blocked_cells' rules: the default, and the program's freshly built and stepped maps (module doc)."""
DYNAMIC_TIMES = (0.0, 2.0, 4.0, 6.0, 8.0, 10.0)


# ----------------------------------------------------------------------------------------------------------------
# starts and directions
# ----------------------------------------------------------------------------------------------------------------
def default_starts(arena_size) -> np.ndarray:
    """The 9 start/goal candidates [9, d] (m): {4, L/2, L - 4} on x and y ({4, 25, 46}^2 in a 50 m arena); in 3D at
    z = L_z / 2 (10 m in a 20 m volume)."""
    size = np.asarray(arena_size, dtype=float)
    xs = [4.0, size[0] / 2.0, size[0] - 4.0]
    ys = [4.0, size[1] / 2.0, size[1] - 4.0]
    pts = np.array(list(itertools.product(xs, ys)), dtype=float)
    if size.shape[0] == 3:
        pts = np.column_stack([pts, np.full(len(pts), size[2] / 2.0)])
    return pts


def neighbour_steps(dims: int, horizontal: bool = False) -> np.ndarray:
    """Integer neighbour steps [m, d]: 2D (and 3D horizontal) the 8 steps at 0, 45, ..., 315 deg; 3D the 26 steps
    of the 3 x 3 x 3 neighbourhood (the 8 horizontal ones first, then the 9 with dz = +1, then the 9 with dz = -1)."""
    ring = np.array([[1, 0], [1, 1], [0, 1], [-1, 1], [-1, 0], [-1, -1], [0, -1], [1, -1]], dtype=int)
    if dims == 2:
        return ring
    flat = np.column_stack([ring, np.zeros(8, dtype=int)])
    if horizontal:
        return flat
    layer = np.array([[0, 0]] + ring.tolist(), dtype=int)
    up = np.column_stack([layer, np.ones(9, dtype=int)])
    return np.concatenate([flat, up, -up])


def unit_directions(dims: int, horizontal: bool = False) -> np.ndarray:
    """The neighbour steps as unit vectors [m, d] (45 deg apart in 2D)."""
    steps = neighbour_steps(dims, horizontal).astype(float)
    return steps / np.linalg.norm(steps, axis=1, keepdims=True)


# ----------------------------------------------------------------------------------------------------------------
# exact ray casting (vectorised over origins x directions)
# ----------------------------------------------------------------------------------------------------------------
def ray_spheres(origins: np.ndarray, dirs: np.ndarray, centres: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Entry distance [n, m] of rays o + t u (t >= 0) into the nearest of the discs/balls (centres [N, k], radii [N])
    over the first k axes of origins [n, D] and dirs [m, D]; 0 from inside, inf on a miss or a tangent graze.
    t is in units of |u| (k < D gives infinite cylinders along the remaining axes, e.g. pillars in 3D)."""
    n, m = origins.shape[0], dirs.shape[0]
    out = np.full((n, m), np.inf)
    if centres.shape[0] == 0 or n == 0 or m == 0:
        return out
    k = centres.shape[1]
    o, u = origins[:, :k], dirs[:, :k]
    a = np.sum(u * u, axis=1)                                        # [m]
    step = max(1, limits.CHUNK_ELEMENTS // (n * m))
    for s in range(0, centres.shape[0], step):
        rel = centres[None, s:s + step, :] - o[:, None, :]          # [n, N, k]
        c = np.sum(rel * rel, axis=2) - radii[None, s:s + step] ** 2  # [n, N]
        b = np.einsum("nNk,mk->nmN", rel, u)                        # [n, m, N]
        disc = b * b - a[None, :, None] * c[:, None, :]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (b - np.sqrt(np.maximum(disc, 0.0))) / a[None, :, None]
        t = np.where((disc > 0.0) & (b > 0.0) & (a[None, :, None] > 0.0), t, np.inf)
        t = np.where(c[:, None, :] < 0.0, 0.0, np.maximum(t, 0.0))
        out = np.minimum(out, t.min(axis=2))
    return out


def _ray_slab(o: np.ndarray, u: np.ndarray, half: np.ndarray) -> np.ndarray:
    """Entry distance [n, m] of rays (origins o [n, d], dirs u [m, d], box frame) into the box |x_i| < half_i."""
    lo = np.full((o.shape[0], u.shape[0]), -np.inf)
    hi = np.full_like(lo, np.inf)
    for i in range(o.shape[1]):
        oi, ui = o[:, i][:, None], u[:, i][None, :]
        with np.errstate(divide="ignore", invalid="ignore"):
            t1 = (-half[i] - oi) / ui
            t2 = (half[i] - oi) / ui
        inside = np.abs(oi) < half[i]
        par = ui == 0.0
        a = np.where(par, np.where(inside, -np.inf, np.inf), np.minimum(t1, t2))
        b = np.where(par, np.where(inside, np.inf, -np.inf), np.maximum(t1, t2))
        lo = np.maximum(lo, a)
        hi = np.minimum(hi, b)
    return np.where((hi > lo) & (hi > 0.0), np.maximum(lo, 0.0), np.inf)


def ray_rounded_box(o: np.ndarray, u: np.ndarray, half: np.ndarray, radius: float) -> np.ndarray:
    """Exact entry distance [n, m] of rays (box frame: origins [n, d], unit dirs [m, d]) into the box of half extents
    ``half`` inflated by ``radius`` (Minkowski sum with a disc/ball). The inflated box is the union of the box grown
    by ``radius`` along one axis at a time, (3D) the 12 edge cylinders and the 2^d corner discs/balls; the first
    entry into a union is the smallest entry into its members."""
    d = o.shape[1]
    best = np.full((o.shape[0], u.shape[0]), np.inf)
    for i in range(d):
        grown = half.copy()
        grown[i] += radius
        best = np.minimum(best, _ray_slab(o, u, grown))
    corners = np.array(list(itertools.product(*[(-h, h) for h in half])), dtype=float)
    best = np.minimum(best, ray_spheres(o, u, corners, np.full(len(corners), radius)))
    if d == 3:
        for axis in range(3):
            others = [a for a in range(3) if a != axis]
            centres = np.array(list(itertools.product(*[(-half[a], half[a]) for a in others])), dtype=float)
            t = np.full_like(best, np.inf)
            for cen in centres:  # 4 edges along ``axis``: circle in the other two coordinates, then the axial range
                te = ray_spheres(o[:, others], u[:, others], cen[None, :], np.array([radius]))
                along = o[:, axis][:, None] + np.where(np.isfinite(te), te, 0.0) * u[:, axis][None, :]
                t = np.minimum(t, np.where(np.isfinite(te) & (np.abs(along) <= half[axis]), te, np.inf))
            best = np.minimum(best, t)
    return best


def ray_static(origins: np.ndarray, dirs: np.ndarray, body: StaticBody, inflate: float) -> np.ndarray:
    """Entry distance [n, m] (m) of rays from origins [n, d] along unit dirs [m, d] into a static body's footprint
    inflated by ``inflate`` (m): pillars exactly (disc / infinite vertical cylinder), boxes exactly (rounded
    rectangle / rounded cuboid, yaw about z)."""
    d = origins.shape[1]
    c = np.asarray(body.center, dtype=float)[:d]
    if body.kind == "pillar":
        return ray_spheres(origins, dirs, c[None, :2], np.array([body.radius + inflate]))
    cy, sy = np.cos(body.yaw), np.sin(body.yaw)
    rot = np.eye(d)
    rot[:2, :2] = [[cy, sy], [-sy, cy]]                              # world -> body frame
    o = (origins - c[None, :]) @ rot.T
    u = dirs @ rot.T
    half = np.asarray(body.size, dtype=float)[:d] / 2.0
    return ray_rounded_box(o, u, half, inflate)


def ray_walls(origins: np.ndarray, dirs: np.ndarray, arena_size: np.ndarray, inflate: float) -> np.ndarray:
    """Distance [n, m] (m) along unit dirs [m, d] until a coordinate reaches ``inflate`` or L - inflate."""
    lo, hi = inflate, np.asarray(arena_size, dtype=float) - inflate
    out = np.full((origins.shape[0], dirs.shape[0]), np.inf)
    for i in range(origins.shape[1]):
        oi, ui = origins[:, i][:, None], dirs[:, i][None, :]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(ui > 0, (hi[i] - oi) / ui, np.where(ui < 0, (lo - oi) / ui, np.inf))
        out = np.minimum(out, np.maximum(t, 0.0))
    return out


def free_distances(rollout, k: int, starts: np.ndarray, dirs: np.ndarray, mav_radius: float,
                   include_static: bool = True) -> np.ndarray:
    """Exact traversability distances [n, m] (m) at step k: min over obstacles, static bodies and walls."""
    pos, _ = rollout.at(k)
    bodies = getattr(rollout, "bodies", None)
    d = ray_walls(starts, dirs, rollout.arena_size, mav_radius)
    if bodies is None:
        d = np.minimum(d, ray_spheres(starts, dirs, pos, rollout.radii + mav_radius))
    if include_static:
        for body in rollout.static:
            d = np.minimum(d, ray_static(starts, dirs, body, mav_radius))
    if bodies is not None and starts.shape[0] and dirs.shape[0]:
        d = shape_distances(rollout, k, starts, dirs, mav_radius, d, "all" if include_static else "moving")
    return d


def shape_distances(rollout, k: int, starts: np.ndarray, dirs: np.ndarray, inflate: float, cap: np.ndarray,
                    which: str) -> np.ndarray:
    """Distances [n, m] (m) along rays from starts [n, d] along unit dirs [m, d] until the MAV ball of radius
    ``inflate`` touches an imported body's real shape (``which``: "all", "static", "moving") at step k, by sphere
    tracing on the exact signed-distance field; at most ``cap`` [n, m] (e.g. the walls' distance)."""
    n, m = starts.shape[0], dirs.shape[0]
    o3 = np.repeat(plane_points(rollout, starts), m, axis=0)
    u3 = np.zeros((n * m, 3))
    u3[:, :rollout.dims] = np.tile(dirs, (n, 1))
    cap = np.asarray(cap, dtype=float).reshape(-1)
    finite = np.isfinite(cap)
    out = cap.copy()
    if np.any(finite):
        idx = np.flatnonzero(finite)
        out[idx] = rollout.bodies.field().march(o3[idx], u3[idx], inflate, cap[idx], k, which)
    return out.reshape(n, m)


# ----------------------------------------------------------------------------------------------------------------
# grid mode
# ----------------------------------------------------------------------------------------------------------------
def _cell_indices(shape: tuple[int, ...]) -> np.ndarray:
    """Integer indices [C, d] of every cell of a grid of ``shape``, in C order."""
    return np.indices(shape).reshape(len(shape), -1).T


def _mark_discs(blocked: np.ndarray, centres: np.ndarray, pos: np.ndarray, radii: np.ndarray,
                closed: bool) -> None:
    """blocked[c] |= cell centre c [C, d] lies inside obstacle i (distance < r_i; ``closed``: <= r_i)."""
    n = pos.shape[0]
    step = max(1, limits.CHUNK_ELEMENTS // max(1, centres.shape[0] * centres.shape[1]))
    for s in range(0, n, step):
        d2 = np.zeros((centres.shape[0], min(step, n - s)))
        for a in range(centres.shape[1]):
            diff = centres[:, None, a] - pos[None, s:s + step, a]
            d2 += diff * diff
        r2 = radii[None, s:s + step] ** 2
        blocked |= np.any(d2 <= r2 if closed else d2 < r2, axis=1)


def _mark_squares(blocked: np.ndarray, idx: np.ndarray, pos: np.ndarray, radii: np.ndarray, cell: float) -> None:
    """blocked[c] |= cell c (indices [C, d]) is within floor(r_i / cell) cells, on every axis, of the cell holding
    obstacle i's centre (the thesis program's per-step marking of a dynamic obstacle)."""
    n = pos.shape[0]
    home = np.floor(pos / cell).astype(np.int64)                              # [N, d]
    reach = np.floor(radii / cell).astype(np.int64)                           # [N]
    step = max(1, limits.CHUNK_ELEMENTS // max(1, idx.shape[0] * idx.shape[1]))
    for s in range(0, n, step):
        near = np.abs(idx[:, None, :] - home[None, s:s + step, :]) <= reach[None, s:s + step, None]
        blocked |= np.any(np.all(near, axis=2), axis=1)


def blocked_cells(rollout, k: int, cell: float, include_static: bool = True,
                  rule: str = "centre_inside") -> np.ndarray:
    """Boolean grid (shape ceil(L / cell) per axis) of the cells blocked at step k under ``rule`` (module doc):
    "centre_inside": the cell centre lies inside an obstacle (distance < r_i), inside a static body, or outside
    the arena; "program_reset" / "program_step": the thesis program's freshly built / stepped map (obstacles by
    centre inside or on the disc / by the floor(r_i / cell) square; its wall cells are outside the arena)."""
    if rule not in CELL_RULES:
        raise ConfigError("rule", f"must be one of {', '.join(CELL_RULES)}", rule)
    limits.check_limit("cell", "grid cells (the arena's extents / cell)", limits.grid_count(rollout.arena_size, cell),
                       limits.MAX_METRIC_SAMPLES, cell)
    shape = tuple(int(np.ceil(L / cell - 1e-9)) for L in rollout.arena_size)
    idx = _cell_indices(shape)
    centres = (idx + 0.5) * cell
    blocked = np.any(centres > rollout.arena_size[None, :], axis=1)
    pos, _ = rollout.at(k)
    bodies = getattr(rollout, "bodies", None)
    if rule == "centre_inside":
        if bodies is not None:
            which = "all" if include_static else "moving"
            blocked |= bodies.field().distance(plane_points(rollout, centres), k, which) < 0.0
        else:
            _mark_discs(blocked, centres, pos, rollout.radii, closed=False)
        if include_static:
            for body in rollout.static:
                blocked |= body.footprint_distance(centres) < 0.0
        return blocked.reshape(shape)
    if bodies is not None and include_static and not bodies.moving.all():
        blocked |= bodies.field().distance(plane_points(rollout, centres), k, "static") <= 0.0
    if rule == "program_reset":
        _mark_discs(blocked, centres, pos, rollout.radii, closed=True)
    else:
        _mark_squares(blocked, idx, pos, rollout.radii, cell)
    if include_static:
        for body in rollout.static:
            blocked |= body.footprint_distance(centres) <= 0.0
    return blocked.reshape(shape)


def walk_distances(blocked: np.ndarray, starts: np.ndarray, steps: np.ndarray, cell: float) -> np.ndarray:
    """Cell-walk distances [n, m] (m): from each start's cell, the free cells walked along each integer step before
    the first blocked or out-of-range cell, times cell x |step|; 0 when the start's cell is blocked."""
    shape = np.array(blocked.shape)
    first = np.floor(starts / cell).astype(int)                              # [n, d]
    ks = np.arange(0, int(shape.max()) + 2)
    cells = first[:, None, None, :] + ks[None, None, :, None] * steps[None, :, None, :]   # [n, m, K, d]
    inside = np.all((cells >= 0) & (cells < shape), axis=-1)
    idx = tuple(np.clip(cells[..., a], 0, shape[a] - 1) for a in range(len(shape)))
    stop = ~inside | blocked[idx]
    walked = np.where(stop[:, :, 0], 0, np.argmax(stop, axis=2) - 1)      # free cells before the first stop
    return walked * cell * np.linalg.norm(steps, axis=1)[None, :]


# ----------------------------------------------------------------------------------------------------------------
# metrics
# ----------------------------------------------------------------------------------------------------------------
def _starts(rollout, starts, spacing, margin, mav_radius) -> tuple[np.ndarray, int]:
    if starts is not None:
        pts = np.asarray(starts, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != rollout.dims:
            raise ConfigError("starts", f"must be an array [n, {rollout.dims}]", jsonable(pts))
    elif spacing is None:
        pts = default_starts(rollout.arena_size)
    else:
        pts = grid_samples(rollout.arena_size, positive("spacing", spacing), float(margin))
    keep = outside_geometry(rollout, pts, mav_radius)
    return pts[keep], int(np.count_nonzero(~keep))


def _distances_at(rollout, k, pts, horizontal, mode, cell, mav_radius, include_static,
                  rule: str = "centre_inside") -> np.ndarray:
    if mode == "exact":
        return free_distances(rollout, k, pts, unit_directions(rollout.dims, horizontal), mav_radius, include_static)
    blocked = blocked_cells(rollout, k, cell, include_static, rule)
    return walk_distances(blocked, pts, neighbour_steps(rollout.dims, horizontal), cell)


def _check(mode: str, cell: float, marking: str = "centre_inside") -> float:
    if mode not in MODES:
        raise ConfigError("mode", f"must be one of {', '.join(MODES)}", mode)
    if marking not in MARKINGS:
        raise ConfigError("marking", f"must be one of {', '.join(MARKINGS)}", marking)
    if marking != "centre_inside" and mode != "grid":
        raise ConfigError("marking", 'marks grid cells: it needs mode = "grid"', marking)
    return positive("cell", cell)


def traversability(rollout, *, time: float = 0.0, starts=None, spacing: float | None = None, margin: float = 5.0,
                   mav_radius: float = 1.0, horizontal: bool = False, mode: str = "exact", cell: float = 1.0,
                   include_static: bool = True, marking: str = "centre_inside",
                   name: str = "traversability") -> MetricResult:
    """Traversability (thesis eq. 3-2, m): mean free straight-line distance over starts x directions at ``time``.

    Starts: ``starts`` [n, d], else with ``spacing`` None the 9 start/goal candidates {4, L/2, L - 4}^2 (3D at
    z = L_z / 2), else grid_samples(arena, spacing, margin); starts whose MAV overlaps static geometry are left out
    (n_excluded). Directions: 8 at 45 deg (3D: 26, or the 8 horizontal ones with ``horizontal``). Modes "exact"
    (ray casting, see module doc) and "grid" (the thesis' cell walk with ``cell`` m cells; mav_radius then only
    excludes starts). marking (grid mode): "centre_inside" or "program" (the thesis program's freshly built map:
    wall ring, centre inside or on a disc; module doc). per_sample: distances [n, m] (m); stderr = std / sqrt(n m).
    """
    t0 = _time.perf_counter()
    cell = _check(mode, cell, marking)
    mav_radius = positive("mav_radius", mav_radius)
    k = rollout.step_index(float(time))
    pts, n_excl = _starts(rollout, starts, spacing, margin, mav_radius)
    rule = "program_reset" if marking == "program" else marking
    per_sample = _distances_at(rollout, k, pts, horizontal, mode, cell, mav_radius, include_static, rule)
    value, err = summary(per_sample)
    params = {"time": float(time), "starts": jsonable(pts), "spacing": None if spacing is None else float(spacing),
              "margin": float(margin), "mav_radius": mav_radius, "horizontal": bool(horizontal), "mode": mode,
              "cell": cell, "include_static": bool(include_static), "marking": marking,
              "n_directions": int(per_sample.shape[1]) if per_sample.ndim == 2 else 0}
    per_sample.setflags(write=False)
    return MetricResult(name, value, params, int(pts.shape[0]), n_excl, per_sample, err, {},
                        _time.perf_counter() - t0)


def traversability_dense(rollout, *, time: float = 0.0, starts=None, spacing: float | None = 5.0,
                         margin: float = 5.0, mav_radius: float = 1.0, horizontal: bool = False, mode: str = "exact",
                         cell: float = 1.0, include_static: bool = True,
                         marking: str = "centre_inside") -> MetricResult:
    """Dense traversability (thesis eq. 3-2, m): starts on the 5 m grid 5, 10, ..., L - 5 (81 in 2D); see
    traversability()."""
    return traversability(rollout, time=time, starts=starts, spacing=spacing, margin=margin, mav_radius=mav_radius,
                          horizontal=horizontal, mode=mode, cell=cell, include_static=include_static,
                          marking=marking, name="traversability_dense")


def dynamic_traversability(rollout, *, times=DYNAMIC_TIMES, starts=None, spacing: float | None = None,
                           margin: float = 5.0, mav_radius: float = 1.0, horizontal: bool = False,
                           mode: str = "exact", cell: float = 1.0, include_static: bool = True,
                           marking: str = "centre_inside") -> MetricResult:
    """Dynamic traversability (thesis eq. 3-3, m): traversability at each of ``times`` (default 0, 2, ..., 10 s),
    averaged over times x starts x directions. per_sample: distances [n_times, n, m] (m). marking "program": the
    thesis program's stepped maps (wall ring, floor(r / cell) squares; module doc). Other parameters as in
    traversability()."""
    t0 = _time.perf_counter()
    cell = _check(mode, cell, marking)
    rule = "program_step" if marking == "program" else marking
    mav_radius = positive("mav_radius", mav_radius)
    ts = [float(t) for t in np.atleast_1d(np.asarray(times, dtype=float))]
    if not ts:
        raise ConfigError("times", "must not be empty", jsonable(times))
    ks = [rollout.step_index(t) for t in ts]
    pts, n_excl = _starts(rollout, starts, spacing, margin, mav_radius)
    per_sample = np.stack([_distances_at(rollout, k, pts, horizontal, mode, cell, mav_radius, include_static, rule)
                           for k in ks])
    value, err = summary(per_sample)
    params = {"times": ts, "starts": jsonable(pts), "spacing": None if spacing is None else float(spacing),
              "margin": float(margin), "mav_radius": mav_radius, "horizontal": bool(horizontal), "mode": mode,
              "cell": cell, "include_static": bool(include_static), "marking": marking}
    per_sample.setflags(write=False)
    return MetricResult("dynamic_traversability", value, params, int(pts.shape[0]), n_excl, per_sample, err, {},
                        _time.perf_counter() - t0)
