"""Static-free routes and the task metrics along them (pbdyn.metrics.route): analytic shortest paths past a wall,
blocked and disconnected tasks, 3D, an imported world's shelves, the grid search against scipy's Dijkstra, the
route metrics against the survivability kernel and the corridor metrics, and the time of a map's reference tasks."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from pbdyn.metrics.analytic import survival_times
from pbdyn.metrics.route import (GRID_FACTOR, RouteGrid, grid_path, neighbour_offsets, route_detour, route_flux,
                                 route_grid, route_metrics, route_points, route_survivability, static_clearance,
                                 static_route)
from pbdyn.metrics.survivability import split_static
from pbdyn.metrics.task import corridor_flux, corridor_points, corridor_survivability
from pbdyn.world.geometry import StaticBody
from tests.conftest import SCENARIOS
from tests.test_metrics import empty, make_rollout

R, CELL = 1.0, 0.5
TIGHT = 0.15
"""Measured accuracy (m) of the refined route on the analytic cases at cell 0.5 m (the module doc's claim)."""


def delta(dims: int, cell: float = CELL) -> float:
    """The clearance the route may give up (module doc): cell sqrt(d) / 2 + cell / 8."""
    return cell * math.sqrt(dims) / 2.0 + cell / 8.0


def around_corners(s, corner, rho: float, flat: float) -> float:
    """Shortest path (m) from s up over a corner (a disc of radius rho in the plane of the detour), along a flat top
    of length ``flat`` and down, symmetric: two tangents and two arcs."""
    dx, dy = corner[0] - s[0], corner[1] - s[1]
    dist = math.hypot(dx, dy)
    turn = math.atan2(dy, dx) + math.asin(rho / dist)
    return 2.0 * (math.sqrt(dist * dist - rho * rho) + rho * turn) + flat


def check_bounds(length: float, exact, dims: int) -> None:
    """L*(r - delta) <= length <= c_d (L*(r + cell sqrt(d) / 2) + sqrt(d) cell), and within TIGHT of L*(r)."""
    assert exact(R - delta(dims)) - 1e-9 <= length
    assert length <= GRID_FACTOR[dims] * (exact(R + CELL * math.sqrt(dims) / 2) + math.sqrt(dims) * CELL)
    assert abs(length - exact(R)) < TIGHT


def dense(waypoints: np.ndarray, step: float = 0.02) -> np.ndarray:
    out = [a + np.linspace(0.0, 1.0, int(np.ceil(np.linalg.norm(b - a) / step)) + 1)[:, None] * (b - a)
           for a, b in zip(waypoints[:-1], waypoints[1:])]
    return np.concatenate(out)


GAP_WALL = (StaticBody("box", (25.0, 18.0), size=(2.0, 38.0)),      # x 24..26, y -1..37
            StaticBody("box", (25.0, 47.0), size=(2.0, 8.0)))       # y 43..51: a gap y 37..43
S2, G2 = (10.0, 10.0), (40.0, 10.0)


@pytest.mark.parametrize("size, s, g", [((50.0, 50.0), (4.0, 4.0), (46.0, 25.0)),
                                        ((50.0, 50.0, 20.0), (4.0, 4.0, 10.0), (46.0, 46.0, 3.0))])
def test_empty_arena_gives_the_straight_segment(size, s, g):
    r = static_route(empty(size), s, g)
    assert r.exists and r.status == "ok"
    np.testing.assert_array_equal(r.waypoints, [s, g])
    assert r.detour == pytest.approx(1.0, abs=1e-12) and r.straight == pytest.approx(math.dist(s, g))
    assert r.detour <= GRID_FACTOR[len(size)] * (1.0 + math.sqrt(len(size)) * CELL / r.straight)


def test_a_wall_with_one_gap_sends_the_route_through_it():
    ro = empty(static=GAP_WALL)
    r = static_route(ro, S2, G2)
    assert r.exists and r.status == "ok"
    w = r.waypoints
    k = int(np.flatnonzero((w[:-1, 0] < 25.0) & (w[1:, 0] >= 25.0))[0])
    y = w[k, 1] + (25.0 - w[k, 0]) / (w[k + 1, 0] - w[k, 0]) * (w[k + 1, 1] - w[k, 1])
    assert 38.0 - delta(2) <= y <= 42.0                                   # the gap, less the MAV's radius
    check_bounds(r.length, lambda rho: around_corners(S2, (24.0, 37.0), rho, 2.0), 2)
    assert r.detour == pytest.approx(r.length / 30.0)
    assert static_clearance(ro, dense(w)).min() >= R - delta(2)
    back = static_route(ro, G2, S2)                                       # the same route, reversed
    np.testing.assert_array_equal(back.waypoints, w[::-1])
    assert back.length == r.length
    assert route_detour(ro, S2, G2) == r.detour


def test_blocked_ends_and_no_route_are_reported():
    ro = empty(static=GAP_WALL)
    assert static_route(ro, (25.0, 10.0), G2).status == "start_blocked"          # inside the wall
    assert static_route(ro, (24.5 - R, 10.0), G2).status == "start_blocked"      # within the MAV radius of it
    assert static_route(ro, S2, (0.5, 10.0)).status == "goal_blocked"            # the MAV would leave the arena
    assert static_route(ro, (0.5, 10.0), S2).status == "start_blocked"
    closed = empty(static=(StaticBody("box", (25.0, 25.0), size=(2.0, 52.0)),))
    r = static_route(closed, S2, G2)
    assert (r.exists, r.status, r.waypoints.shape) == (False, "no_route", (0, 2))
    assert math.isnan(r.length) and math.isnan(r.detour) and r.straight == 30.0
    assert math.isnan(route_detour(closed, S2, G2))
    assert route_survivability(closed, S2, G2) == (pytest.approx(np.nan, nan_ok=True), 0)
    assert route_flux(closed, S2, G2)[1] == 0
    res = route_metrics(closed, starts=[S2, G2, (5.0, 40.0)])
    d = res["route_detour"]
    assert (d.n_samples, d.n_excluded) == (2, 4) and d.value == 1.0      # only the pairs on the same side
    assert d.extra["status"] == ["no_route", "ok", "no_route", "no_route", "ok", "no_route"]


def test_3d_route_climbs_over_a_wall():
    wall = (StaticBody("box", (25.0, 25.0, 7.0), size=(2.0, 52.0, 14.0)),)   # x 24..26, full y, z 0..14
    ro = empty((50.0, 50.0, 20.0), static=wall)
    s, g = (10.0, 25.0, 5.0), (40.0, 25.0, 5.0)
    r = static_route(ro, s, g)
    assert r.exists and np.all(np.abs(r.waypoints[:, 1] - 25.0) < 1e-9)
    assert np.max(r.waypoints[:, 2]) >= 15.0 - delta(3)
    check_bounds(r.length, lambda rho: around_corners((10.0, 5.0), (24.0, 14.0), rho, 2.0), 3)
    assert static_clearance(ro, dense(r.waypoints)).min() >= R - delta(3)
    lid = empty((50.0, 50.0, 20.0), static=(StaticBody("box", (25.0, 25.0, 10.0), size=(2.0, 52.0, 22.0)),))
    assert static_route(lid, s, g).status == "no_route"


@pytest.fixture(scope="module")
def warehouse():
    from pbdyn.config import load_scenario
    from pbdyn.world.maps import enumerate_maps
    from pbdyn.world.rollout import build_rollout

    sc = load_scenario(SCENARIOS / "worlds" / "warehouse_2d.toml")
    return build_rollout(sc, enumerate_maps(sc)[0], 13.0), np.asarray(sc.task.candidates, dtype=float)


def test_imported_world_routes_avoid_the_shelves(warehouse):
    ro, cands = warehouse
    field = ro.bodies.field()
    still = np.flatnonzero(~ro.bodies.moving)
    grid = route_grid(ro)
    detours = []
    for i, j in [(0, 8), (2, 6), (1, 7), (0, 5), (3, 5)]:
        r = static_route(ro, cands[i], cands[j], grid=grid)
        assert r.exists
        detours.append(r.detour)
        for pts in (r.waypoints, dense(r.waypoints)):
            q = np.column_stack([pts, np.full(len(pts), ro.meta["flight_height"])])
            for b in still:
                assert field.body_distance(int(b), q, 0).min() >= R - CELL
    assert detours[0] > 1.01 and detours[1] > 1.01          # the diagonals cross shelves
    assert detours[2] == 1.0                                 # the middle row is an open aisle


def grid_distance_reference(free: np.ndarray, a: tuple, b: tuple) -> float:
    """The reference twin of grid_path's length (cells): scipy's Dijkstra on the 8/26-connected graph of the free
    nodes."""
    shape = free.shape
    idx = np.indices(shape).reshape(len(shape), -1).T
    rows, cols, w = [], [], []
    for step in neighbour_offsets(len(shape)):
        nb = idx + step
        ok = np.all((nb >= 0) & (nb < shape), axis=1)
        src, dst = idx[ok], nb[ok]
        ok = free[tuple(src.T)] & free[tuple(dst.T)]
        rows.append(np.ravel_multi_index(tuple(src[ok].T), shape))
        cols.append(np.ravel_multi_index(tuple(dst[ok].T), shape))
        w.append(np.full(int(ok.sum()), float(np.linalg.norm(step))))
    n = int(np.prod(shape))
    graph = coo_matrix((np.concatenate(w), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)).tocsr()
    dist = dijkstra(graph, indices=int(np.ravel_multi_index(a, shape)))
    return float(dist[np.ravel_multi_index(b, shape)])


@pytest.mark.parametrize("shape", [(40, 30), (14, 12, 9)])
def test_grid_search_matches_scipy_dijkstra(shape):
    rng = np.random.default_rng(np.random.SeedSequence([7, len(shape)]))
    free = rng.random(shape) > 0.3
    grid = RouteGrid(1.0, 1.0, free.astype(float), free, np.zeros(shape, dtype=int), np.array(shape, float))
    nodes = np.argwhere(free)
    for _ in range(6):
        a, b = (tuple(int(x) for x in nodes[k]) for k in rng.choice(len(nodes), 2, replace=False))
        want = grid_distance_reference(free, a, b)
        got, path = grid_path(grid, a, b)
        assert got == pytest.approx(want, rel=1e-12) if np.isfinite(want) else not np.isfinite(got)
        if np.isfinite(want):
            steps = np.diff(path, axis=0)
            assert np.all(free[tuple(path.T)]) and np.all(np.abs(steps) <= 1)
            assert float(np.sum(np.linalg.norm(steps, axis=1))) == pytest.approx(got, rel=1e-12)


def test_route_metrics_are_the_corridor_metrics_on_the_route_samples():
    pillar = StaticBody("pillar", (25.0, 26.0), radius=3.0)
    ro = make_rollout([[25.0, 40.0], [30.0, 10.0]], [[0.0, -2.0], [-1.0, 2.5]], [1.0, 1.5], static=(pillar,),
                      horizon=14.0)
    s, g = (4.0, 25.0), (46.0, 25.0)
    r = static_route(ro, s, g)
    assert r.detour > 1.0
    pts, _ = split_static(ro, route_points(r.waypoints, ro.arena_size), R)
    want = float(np.mean(survival_times(ro, pts)))
    assert route_survivability(ro, s, g) == (pytest.approx(want, rel=1e-12), pts.shape[0])
    assert route_survivability(ro, g, s) == route_survivability(ro, s, g)             # same samples reversed
    assert route_flux(ro, s, g, route=r)[1] == pts.shape[0]
    # a straight route: the corridor's own samples and values
    open_ro = make_rollout([[25.0, 40.0]], [[0.0, -2.0]], [1.0], horizon=14.0)
    straight = static_route(open_ro, s, g)
    np.testing.assert_array_equal(route_points(straight.waypoints, open_ro.arena_size),
                                  corridor_points(s, g, open_ro.arena_size))
    assert route_survivability(open_ro, s, g) == corridor_survivability(open_ro, s, g)
    assert route_flux(open_ro, s, g) == corridor_flux(open_ro, s, g)
    # the map-level means: per task the task functions
    starts = [(4.0, 25.0), (46.0, 25.0), (25.0, 46.0)]
    res = route_metrics(ro, starts=starts, pairs=[(0, 1), (1, 0), (2, 0)])
    for k, (i, j) in enumerate([(0, 1), (1, 0), (2, 0)]):
        assert res["route_detour"].per_sample[k] == route_detour(ro, starts[i], starts[j])
        assert res["route_survivability"].per_sample[k] == pytest.approx(
            route_survivability(ro, starts[i], starts[j])[0], rel=1e-12)
        assert res["route_flux"].per_sample[k] == pytest.approx(route_flux(ro, starts[i], starts[j])[0], rel=1e-12)
    assert res["route_detour"].value == pytest.approx(np.mean(res["route_detour"].per_sample))


def test_time_of_a_maps_reference_tasks():
    from pbdyn.analysis.scale import reference_pairs
    from pbdyn.config import load_scenario
    from pbdyn.world.maps import enumerate_maps
    from pbdyn.world.rollout import build_rollout

    for name in ("structured_2d", "structured_3d"):
        sc = load_scenario(SCENARIOS / "datasets" / f"{name}.toml")
        spec = next(m for m in enumerate_maps(sc) if m.setup.get("structure") == "walls")
        ro = build_rollout(sc, spec, 13.0)
        cands = np.asarray(sc.task.candidates, dtype=float)
        pairs = reference_pairs(cands)
        route_metrics(ro, starts=cands[:2], pairs=[(0, 1)])                # compiled code loaded
        t0 = time.perf_counter()
        res = route_metrics(ro, starts=cands, pairs=pairs)
        wall = time.perf_counter() - t0
        print(f"\n{name} (walls map, {len(ro.static)} static bodies): {len(pairs)} reference tasks in {wall:.3f} s; "
              f"mean detour {res['route_detour'].value:.3f}, route survivability "
              f"{res['route_survivability'].value:.2f} s, route flux {res['route_flux'].value:.4f} 1/s")
        assert res["route_detour"].n_samples == len(pairs)
