"""The thesis program's marching depth sensor ([sensor] model = "marching"): ray count, march points, missed thin
bodies, true centres, grid updates against a plain per-point reference, 3D, scenario validation and a real trial."""

from __future__ import annotations

import math
import tomllib

import numpy as np
import pytest

from pbdyn import api, limits
from pbdyn.config import parse_scenario
from pbdyn.errors import ConfigError
from pbdyn.perception import marching
from pbdyn.perception.grid import FREE, OCCUPIED, UNKNOWN, OccupancyGrid
from pbdyn.perception.perceive import Perception
from pbdyn.world.bullet import PyBulletWorld
from pbdyn.world.geometry import StaticBody
from pbdyn.world.imported.urdf_loading import urdf_path
from tests.conftest import SCENARIOS

ARENA = (30.0, 20.0)


def make_world(radii, positions, static=(), dims=2, size=ARENA):
    w = PyBulletWorld(dims=dims, arena_size=size, mav_radius=0.5, obstacle_radii=radii, static_bodies=list(static))
    w.set_obstacle_positions(positions)
    return w


def sensor(world, model="marching", fov=90.0, **kw):
    size = np.asarray(world.arena_size)
    grid = OccupancyGrid(np.zeros(world.dims), size, 1.0)
    res = kw.pop("resolution_deg", 1.0 if world.dims == 2 else 2.0)
    vfov = 60.0 if world.dims == 3 else None
    return Perception(world, grid, fov_deg=fov, range_m=8.0, resolution_deg=res, vfov_deg=vfov, model=model,
                      **kw), grid


def march_reference(world, directions, o, range_m, step, rule="ray"):
    """The reference twin of the marching sensor (pbdyn.perception.marching.march), a plain per-ray, per-point loop
    of the marching rule: (free points, occupied points, seen obstacle ids).
    rule "program": ``step`` along the ray's dominant axis, and the first point at/after the range is still tested
    for obstacles, bodies and walls (the program's loop), never marked free."""
    free, occupied, seen = [], [], set()
    L = np.asarray(world.arena_size)
    for u in directions:
        per = step / np.max(np.abs(u)) if rule == "program" else step
        k_max = int(math.ceil(range_m / per))
        for k in range(k_max + 1):
            t = k * per
            if t >= range_m and rule != "program":
                break
            p = o + t * u
            holders = np.flatnonzero(np.sum((world.obstacle_positions - p) ** 2, axis=1) <= world.obstacle_radii ** 2)
            if holders.shape[0]:
                seen.update(holders.tolist())
                break
            if any(b.footprint_distance(p[None])[0] <= 0.0 for b in world.static_bodies) or np.any(p < 0) \
                    or np.any(p >= L):
                occupied.append(p)
                break
            if t >= range_m:
                break
            free.append(p)
    return np.array(free).reshape(-1, len(o)), np.array(occupied).reshape(-1, len(o)), sorted(seen)


def expected_cells(shape_like: OccupancyGrid, free, occupied):
    g = OccupancyGrid(shape_like.lo, shape_like.hi, shape_like.res)
    if len(free):
        g.mark_free(free)
    if len(occupied):
        g.mark_occupied(occupied)
    return g.cells


# ----------------------------------------------------------------------------------------------- geometry
def test_fifty_rays_edge_to_edge_over_the_fov_and_over_360():
    w = make_world([1.0], [[25.0, 10.0]])
    try:
        perc, _ = sensor(w, rays=50)
        d = perc.directions(0.3)
        assert perc.n_rays == 50 and d.shape == (50, 2)
        ang = np.arctan2(d[:, 1], d[:, 0])
        assert ang[0] == pytest.approx(0.3 - math.pi / 4) and ang[-1] == pytest.approx(0.3 + math.pi / 4)
        np.testing.assert_allclose(np.diff(ang), math.radians(90.0 / 49.0))
        full, _ = sensor(w, fov=360.0, rays=50)                   # FullRange: the program's same count
        a = np.sort(np.mod(np.arctan2(*full.directions(0.0).T[::-1]), 2 * math.pi))
        assert a.shape == (50,)
        np.testing.assert_allclose(np.diff(a), math.radians(7.2))
        derived, _ = sensor(w)                                    # rays None: from resolution_deg, as raycast
        assert derived.n_rays == 91 == sensor(w, model="raycast")[0].n_rays
        np.testing.assert_allclose(marching.march_distances(8.0, 0.9), 0.9 * np.arange(9))
        np.testing.assert_allclose(marching.march_distances(8.0, 2.0), [0.0, 2.0, 4.0, 6.0])   # 8 m is not < 8 m
    finally:
        w.close()


# ----------------------------------------------------------------------------------------------- detection
def test_a_thin_obstacle_between_march_points_is_missed_while_raycast_sees_it():
    # points along +x at x = 10, 10.9, 11.8, ...; the disc spans x 11.05..11.65 on the axis, and off the axis the
    # points at 0.9 and 1.8 m never come within 0.3 m of its centre (1.35 m away)
    w = make_world([0.3, 1.0], [[11.35, 10.0], [10.0, 2.0]])
    try:
        w.set_mav_pose([10.0, 10.0], 0.0)
        march_, _ = sensor(w, rays=50)
        ray_, _ = sensor(w, model="raycast")
        m, r = march_.sense([10.0, 10.0], 0.0), ray_.sense([10.0, 10.0], 0.0)
        assert r.ids.tolist() == [0] and m.ids.tolist() == []
        assert np.all(m.hits == -1) and np.all(m.ranges == 8.0)
        # a step small enough finds it
        fine, _ = sensor(w, rays=50, march_step=0.1)
        assert fine.sense([10.0, 10.0], 0.0).ids.tolist() == [0]
    finally:
        w.close()


def test_detections_are_true_centres_of_every_obstacle_holding_the_hit_point():
    # 0 and 1 overlap and both hold the centre ray's point x = 13.6; 2 is behind them; 3 is outside the fov
    w = make_world([1.0, 0.8, 0.5, 1.0], [[14.0, 10.0], [14.2, 10.0], [17.5, 10.0], [5.0, 10.0]])
    try:
        perc, _ = sensor(w, rays=51, march_step=0.9, noise_std=0.0)
        det = perc.sense([10.0, 10.0], 0.0)
        assert det.ids.tolist() == [0, 1]
        np.testing.assert_array_equal(det.centers, w.obstacle_positions[[0, 1]])
        assert det.n_rays == 51 and int(det.hits[25]) == int(w.obstacle_ids[0])     # the lowest holder
        assert det.ranges[25] == pytest.approx(3.6)
        noisy, _ = sensor(w, rays=51, noise_std=0.05, rng=np.random.default_rng(3))
        d2 = noisy.sense([10.0, 10.0], 0.0)
        assert d2.ids.tolist() == [0, 1] and 0 < np.abs(d2.centers - w.obstacle_positions[[0, 1]]).max() < 0.5
    finally:
        w.close()


def test_free_and_occupied_cells_for_a_pillar_and_a_wall():
    w = make_world([0.5], [[5.0, 5.0]], static=[StaticBody("pillar", (16.0, 10.0), radius=1.0)])
    try:
        perc, grid = sensor(w, rays=1, fov=10.0)                  # one ray, straight ahead
        det = perc.sense([10.0, 10.0], 0.0)
        # points x = 10, 10.9, ..., 14.5 free (cells 11..15 in grid indices: cell i covers [i - 1, i) m); the
        # point 15.4 is inside the pillar: its cell (16, 11) OCCUPIED
        assert int(det.hits[0]) == int(w.static_ids[0]) and det.ranges[0] == pytest.approx(5.4)
        assert {tuple(c) for c in np.argwhere(grid.cells == FREE).tolist()} == {(i, 11) for i in range(11, 16)}
        assert np.argwhere(grid.cells == OCCUPIED).tolist() == [[16, 11]]
        # toward the +x wall from x = 27: 27, 27.9, 28.8, 29.7 free; 30.6 is beyond it: the border cell OCCUPIED
        det = perc.sense([27.0, 15.0], 0.0)
        assert int(det.hits[0]) == int(w.wall_ids[1]) and det.ranges[0] == pytest.approx(3.6)
        assert grid.cells[31, 16] == OCCUPIED and grid.cells[30, 16] == FREE and grid.cells[28, 16] == FREE
        assert det.ids.shape == (0,) and det.centers.shape == (0, 2)
    finally:
        w.close()


@pytest.mark.parametrize("fov", [90.0, 360.0])
@pytest.mark.parametrize("rule", ["ray", "program"])
def test_grid_and_detections_match_a_per_point_reference_on_random_scenes(fov, rule, monkeypatch):
    monkeypatch.setattr(limits, "CHUNK_ELEMENTS", 700)           # several obstacle chunks per scan
    rng = np.random.default_rng(11)
    n = 25
    static = [StaticBody("pillar", (8.0, 6.0), radius=1.2),
              StaticBody("box", (20.0, 12.0), size=(3.0, 1.5), yaw=0.4)]
    w = make_world(rng.uniform(0.3, 1.5, n), rng.uniform(0.0, 1.0, (n, 2)) * ARENA, static)
    try:
        perc, grid = sensor(w, fov=fov, rays=50, march_step=0.9, march_rule=rule)
        kinds = set()
        for _ in range(12):
            w.set_obstacle_positions(rng.uniform(0.0, 1.0, (n, 2)) * ARENA)
            o, yaw = rng.uniform([1.0, 1.0], [29.0, 19.0]), float(rng.uniform(-math.pi, math.pi))
            grid.cells[:] = UNKNOWN
            det = perc.sense(o, yaw)
            kinds |= {w.body_kind(int(b))[0] for b in det.hits}
            free, occ, seen = march_reference(w, perc.directions(yaw), o, 8.0, 0.9, rule)
            assert det.ids.tolist() == seen
            np.testing.assert_array_equal(det.centers, w.obstacle_positions[seen])
            np.testing.assert_array_equal(grid.cells, expected_cells(grid, free, occ))
        assert kinds == {"none", "dynamic", "static", "wall"}
    finally:
        w.close()


def test_3d_spheres_rows_and_reference():
    size = (30.0, 20.0, 12.0)
    rng = np.random.default_rng(5)
    n = 20
    static = [StaticBody("pillar", (8.0, 6.0, 6.0), radius=1.0), StaticBody("box", (20.0, 12.0, 4.0),
                                                                           size=(3.0, 2.0, 3.0))]
    w = make_world(rng.uniform(0.4, 1.5, n), rng.uniform(0.0, 1.0, (n, 3)) * size, static, dims=3, size=size)
    try:
        perc, grid = sensor(w, rays=50)
        assert perc.n_rays == 50 * 31                                # 50 per row x the raycast model's 31 rows
        kinds = set()
        for target in ((8.0, 6.0, 6.0), (20.0, 12.0, 4.0), (29.0, 19.0, 11.0)):   # pillar, box, a corner
            o = np.asarray(target) + rng.uniform([-6.0, -6.0, -2.0], [-3.0, -3.0, 1.0])
            yaw = math.atan2(target[1] - o[1], target[0] - o[0])
            c, s_ = math.cos(yaw), math.sin(yaw)
            ahead = rng.uniform([1.0, -5.0, -3.0], [8.0, 5.0, 3.0], (n, 3))      # obstacles in front of the MAV
            w.set_obstacle_positions(o + ahead @ np.array([[c, s_, 0.0], [-s_, c, 0.0], [0.0, 0.0, 1.0]]))
            grid.cells[:] = UNKNOWN
            det = perc.sense(o, yaw)
            kinds |= {w.body_kind(int(b))[0] for b in det.hits}
            free, occ, seen = march_reference(w, perc.directions(yaw), o, 8.0, 0.9)
            assert det.ids.tolist() == seen and len(seen) > 0
            np.testing.assert_array_equal(grid.cells, expected_cells(grid, free, occ))
        assert kinds == {"none", "dynamic", "static", "wall"}
    finally:
        w.close()
    # a 0.3 m ball between the points at 0.9 and 1.8 m straight ahead: missed; raycast sees it
    w = make_world([0.3], [[11.35, 10.0, 6.0]], dims=3, size=size)
    try:
        w.set_mav_pose([10.0, 10.0, 6.0], 0.0)
        assert sensor(w, rays=50)[0].sense([10.0, 10.0, 6.0], 0.0).ids.tolist() == []
        assert sensor(w, model="raycast")[0].sense([10.0, 10.0, 6.0], 0.0).ids.tolist() == [0]
    finally:
        w.close()


# ----------------------------------------------------------------------------------------------- validation
def base_doc() -> dict:
    with open(SCENARIOS / "quickstart.toml", "rb") as fh:
        return tomllib.load(fh)


@pytest.mark.parametrize("sensor_table, field", [
    ({"model": "laser"}, "sensor.model"),
    ({"model": 3}, "sensor.model"),
    ({"model": "marching", "rays": 0}, "sensor.rays"),
    ({"model": "marching", "rays": 2.5}, "sensor.rays"),
    ({"model": "marching", "rays": True}, "sensor.rays"),
    ({"model": "marching", "rays": 10 ** 7}, "sensor.rays"),
    ({"model": "marching", "march_step": 0.0}, "sensor.march_step"),
    ({"model": "marching", "march_step": -1.0}, "sensor.march_step"),
    ({"model": "marching", "march_step": 9.0}, "sensor.march_step"),          # longer than the 8 m range
    ({"model": "marching", "march_step": "0.9"}, "sensor.march_step"),
    ({"model": "marching", "march_step": 1e-6}, "sensor.march_step"),         # march points per scan limit
    ({"rays": 50}, "sensor.rays"),                                            # only with model = "marching"
    ({"model": "raycast", "march_step": 0.9}, "sensor.march_step"),
])
def test_bad_sensor_fields_are_config_errors_naming_the_field(sensor_table, field):
    doc = base_doc()
    doc["sensor"].update(sensor_table)
    with pytest.raises(ConfigError) as e:
        parse_scenario(doc)
    assert e.value.field == field


def test_scenario_fields_parse_and_perception_checks_its_arguments():
    doc = base_doc()
    doc["sensor"].update({"model": "marching", "rays": 50, "march_step": 0.9})
    s = parse_scenario(doc).sensor
    assert (s.model, s.rays, s.march_step) == ("marching", 50, 0.9)
    d = parse_scenario(base_doc()).sensor
    assert (d.model, d.rays, d.march_step) == ("raycast", None, 0.9)
    w = make_world([1.0], [[25.0, 10.0]])
    try:
        for kw, field in (({"model": "sonar"}, "sensor.model"), ({"rays": 0}, "sensor.rays"),
                          ({"march_step": float("nan")}, "sensor.march_step")):
            with pytest.raises(ConfigError) as e:
                sensor(w, **kw)
            assert e.value.field == field
        w.add_static_urdf(urdf_path("box"), (5.0, 5.0, 2.0))
        with pytest.raises(ConfigError) as e:
            sensor(w)
        assert e.value.field == "sensor.model"
        sensor(w, model="raycast")                                # raycast sees URDF bodies
    finally:
        w.close()


# ----------------------------------------------------------------------------------------------- a trial
def test_a_trial_with_the_marching_sensor_flies():
    doc = base_doc()
    doc["sensor"].update({"model": "marching", "rays": 50})
    doc["obstacles"]["count"] = [30]
    results = {}
    for gaze in ("lookahead", "fullrange"):
        seen = []

        class Watch:
            def on_step(self, env, agent, decision, record):
                assert env.perception.model == "marching" and env.perception.n_rays == 50
                seen.append(len(record.detected))

            def on_end(self, env, agent):
                pass

        res = api.run_trial(parse_scenario(doc), planner="local_primitives", gaze=gaze, observers=[Watch()])
        assert res.outcome in ("success", "dynamic_collision", "static_collision", "freezing", "deadlock")
        assert res.flight_time_s > 1.0
        assert sum(seen) > 0 and res.obstacles_tracked > 0
        results[gaze] = res
    ray = api.run_trial(parse_scenario(base_doc() | {"obstacles": doc["obstacles"]}), planner="local_primitives",
                        gaze="lookahead")
    # 50 rays at 0.9 m steps discover fewer cells per step than 91 rays sampled every 0.25 m
    assert results["lookahead"].grid_discovered / results["lookahead"].flight_time_s \
        < ray.grid_discovered / ray.flight_time_s


def test_the_programs_march_steps_along_the_dominant_axis_and_its_fan_starts_at_minus_half_the_fov():
    """march_rule = "program": 50 rays at yaw - 45 + 1.8 i deg (the last 1.8 deg short of + 45), points 0.9 m apart
    along each ray's dominant axis (1.27 m along a diagonal), and the point at/after 8 m still detects: an obstacle
    at 8.3 m straight ahead is seen (point at 8.1 m), which the "ray" rule (points < 8 m) misses; a 0.3 m obstacle
    2.9 m along the diagonal lies between the program's points (2.55, 3.82 m), and the "ray" rule (2.7 m) sees it."""
    o = np.array([5.0, 10.0])
    diag = math.pi / 4
    w = make_world([0.25, 0.3], [[13.3, 10.0], o + 2.9 * np.array([math.cos(diag), math.sin(diag)])])
    try:
        prog, _ = sensor(w, fov=90.0, rays=50, march_rule="program")
        ang = np.degrees(np.arctan2(prog.directions(0.0)[:, 1], prog.directions(0.0)[:, 0]))
        np.testing.assert_allclose(ang, -45.0 + 1.8 * np.arange(50), atol=1e-9)
        ray, _ = sensor(w, fov=90.0, rays=50)
        assert 0 in prog.sense(o, 0.0).ids.tolist() and 0 not in ray.sense(o, 0.0).ids.tolist()
        assert 1 not in prog.sense(o, diag).ids.tolist() and 1 in ray.sense(o, diag).ids.tolist()
        dirs = prog.directions(diag)
        ts, last = marching.program_march_distances(dirs.T, 8.0, 0.9)
        i = int(np.argmin(np.abs(np.arctan2(dirs[:, 1], dirs[:, 0]) - diag)))
        np.testing.assert_allclose(ts[i, :4], 0.9 * math.sqrt(2.0) * np.arange(4), atol=1e-9)
        assert ts[i, last[i]] >= 8.0 > ts[i, last[i] - 1]
        with pytest.raises(ConfigError):
            sensor(w, march_rule="diagonal")
    finally:
        w.close()
