"""Ray-cast perception: sensor geometry, detection with occlusion, grid updates, noise, quiet stdout."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest

from pbdyn.errors import ConfigError
from pbdyn.perception.grid import FREE, OCCUPIED, UNKNOWN, OccupancyGrid
from pbdyn.perception.perceive import Perception
from pbdyn.perception.sensor import in_fov, ray_directions
from pbdyn.world.bullet import PyBulletWorld
from pbdyn.world.geometry import StaticBody

ARENA = (30.0, 20.0)


@pytest.fixture
def world():
    # Obstacles: 0 ahead (+x) of the MAV at (10, 10); 1 behind it; 2 hidden behind 0; 3 hidden behind the pillar.
    w = PyBulletWorld(dims=2, arena_size=ARENA, mav_radius=0.5, obstacle_radii=[1.0, 1.0, 0.5, 0.5],
                      static_bodies=[StaticBody("pillar", (10.0, 15.0), radius=1.0)])
    w.set_obstacle_positions([[15.0, 10.0], [5.0, 10.0], [17.0, 10.0], [10.0, 17.5]])
    w.set_mav_pose([10.0, 10.0], 0.0)
    yield w
    w.close()


def _perception(world, fov=90.0, **kw):
    grid = OccupancyGrid(np.zeros(2), np.asarray(ARENA), 1.0)
    return Perception(world, grid, fov_deg=fov, range_m=8.0, resolution_deg=1.0, **kw), grid


# ------------------------------------------------------------------------------------------ sensor geometry
def test_ray_fans_2d_limited_and_full_range():
    d = ray_directions(0.5, 90.0, 1.0, 2)
    assert d.shape == (91, 2) and np.allclose(np.linalg.norm(d, axis=1), 1.0)
    ang = np.arctan2(d[:, 1], d[:, 0])
    assert np.isclose(ang[0], 0.5 - math.pi / 4) and np.isclose(ang[-1], 0.5 + math.pi / 4)
    assert np.allclose(np.diff(ang), math.radians(1.0))
    full = ray_directions(0.0, 360.0, 1.0, 2)
    assert full.shape == (360, 2)
    a = np.sort(np.mod(np.arctan2(full[:, 1], full[:, 0]), 2 * np.pi))
    assert np.allclose(np.diff(a), math.radians(1.0)) and np.isclose(a[-1] - a[0], math.radians(359.0))
    assert ray_directions(0.0, 90.0, 2.0, 2).shape == (46, 2)


def test_ray_grid_3d():
    d = ray_directions(1.0, 90.0, 2.0, 3, vfov_deg=60.0, vresolution_deg=2.0)
    assert d.shape == (46 * 31, 3) and np.allclose(np.linalg.norm(d, axis=1), 1.0)
    elev = np.degrees(np.arcsin(d[:, 2]))
    assert np.isclose(elev.min(), -30.0) and np.isclose(elev.max(), 30.0)
    az = np.arctan2(d[:, 1], d[:, 0])
    assert np.isclose(az.min(), 1.0 - math.pi / 4) and np.isclose(az.max(), 1.0 + math.pi / 4)
    mean = d.mean(axis=0)          # the grid is symmetric about (yaw, elevation 0)
    assert np.allclose(mean / np.linalg.norm(mean), [math.cos(1.0), math.sin(1.0), 0.0])
    with pytest.raises(ValueError):
        ray_directions(0.0, 90.0, 2.0, 3)


def test_in_fov_sector_range_full_circle_and_frustum():
    pts = np.array([[3.0, 0.0], [3.0, 2.9], [3.0, 3.1], [-3.0, 0.0], [9.0, 0.0], [0.0, 0.0]])
    assert in_fov(0.0, pts, 90.0, 8.0).tolist() == [True, True, False, False, False, True]
    assert in_fov(math.pi, pts, 90.0, 8.0).tolist() == [False, False, False, True, False, True]
    assert in_fov(0.0, pts, 360.0, 8.0).tolist() == [True, True, True, True, False, True]
    # The wrap-around at +-pi: yaw just below pi still sees a point just past -pi.
    assert in_fov(math.pi - 0.1, np.array([[-5.0, -0.5]]), 90.0, 8.0).tolist() == [True]
    p3 = np.array([[4.0, 0.0, 2.0], [4.0, 0.0, 2.4], [4.0, 0.0, -2.0]])
    assert in_fov(0.0, p3, 90.0, 8.0, vfov_deg=60.0).tolist() == [True, False, True]
    assert in_fov(0.0, p3, 90.0, 8.0).tolist() == [True, True, True]


# ------------------------------------------------------------------------------------------ detection
def test_obstacle_in_fov_is_detected_with_the_body_hit(world):
    perc, _ = _perception(world)
    det = perc.sense([10.0, 10.0], 0.0)
    assert det.ids.tolist() == [0] and det.ids.dtype == np.int64
    assert np.allclose(det.centers, [[15.0, 10.0]])
    assert det.n_rays == 91 and det.hits.shape == (91,)
    assert int(det.hits[45]) == int(world.obstacle_ids[0])           # the centre ray hits obstacle 0's body
    assert math.isclose(det.ranges[45], 4.0, abs_tol=2e-3)


def test_obstacle_behind_is_seen_only_by_a_full_range_sensor(world):
    narrow, _ = _perception(world, fov=90.0)
    assert 1 not in narrow.sense([10.0, 10.0], 0.0).ids
    full, _ = _perception(world, fov=360.0)
    det = full.sense([10.0, 10.0], 0.0)
    assert det.n_rays == 360
    assert det.ids.tolist() == [0, 1]          # 2 is occluded by 0, 3 by the static pillar
    assert np.allclose(det.centers, [[15.0, 10.0], [5.0, 10.0]])


def test_occluded_obstacles_are_not_detected(world):
    perc, _ = _perception(world, fov=90.0)
    det = perc.sense([10.0, 10.0], 0.0)            # 2 sits right behind 0
    assert 2 not in det.ids
    det = perc.sense([10.0, 10.0], math.pi / 2)    # 3 sits right behind the pillar
    assert 3 not in det.ids and det.ids.shape == (0,)
    world.set_obstacle_positions([[15.0, 3.0], [5.0, 10.0], [17.0, 10.0], [10.0, 17.5]])   # move 0 away
    det = perc.sense([10.0, 10.0], 0.0)
    assert det.ids.tolist() == [2] and np.allclose(det.centers, [[17.0, 10.0]])


def test_grid_cells_along_rays_become_free_and_the_pillar_occupied(world):
    perc, grid = _perception(world, fov=90.0)
    assert np.all(grid.cells == UNKNOWN)
    perc.sense([10.0, 10.0], math.pi / 2)          # looking at the pillar at (10, 15), r = 1
    assert grid.value_at(np.array([[10.2, 11.5], [10.2, 12.5], [10.2, 13.5]])).tolist() == [FREE] * 3
    assert grid.value_at(np.array([10.0, 14.0 + 1e-3])) == OCCUPIED        # the pillar's first cell on the ray
    assert grid.value_at(np.array([10.5, 16.5])) == UNKNOWN                 # behind the pillar
    assert grid.value_at(np.array([13.0, 16.5])) == FREE                    # a free ray beside it, to full range
    assert grid.value_at(np.array([10.0, 9.0])) == UNKNOWN                  # behind the MAV
    occupied = np.argwhere(grid.cells == OCCUPIED)
    centres = grid.cell_center(occupied)
    assert occupied.shape[0] >= 1 and np.all(np.hypot(centres[:, 0] - 10.0, centres[:, 1] - 15.0) < 1.0 + 0.75)
    # A dynamic obstacle is never mapped: the cells of obstacle 0 are FREE up to its surface and not OCCUPIED.
    perc.sense([10.0, 10.0], 0.0)
    assert grid.value_at(np.array([13.5, 10.0])) == FREE
    assert np.all(grid.value_at(np.array([[14.5, 10.0], [15.0, 10.0]])) != OCCUPIED)
    # Walls are mapped: look west from near the wall.
    perc.sense([4.0, 4.0], math.pi)
    assert grid.value_at(np.array([-0.5, 4.0])) == OCCUPIED
    assert grid.value_at(np.array([0.5, 4.0])) == FREE


def test_noise_is_gaussian_from_the_given_generator(world):
    a, _ = _perception(world, noise_std=0.2, rng=np.random.default_rng(7))
    b, _ = _perception(world, noise_std=0.2, rng=np.random.default_rng(7))
    da, db = a.sense([10.0, 10.0], 0.0), b.sense([10.0, 10.0], 0.0)
    assert np.array_equal(da.centers, db.centers)
    assert not np.allclose(da.centers, [[15.0, 10.0]])
    errs = np.concatenate([a.sense([10.0, 10.0], 0.0).centers - [15.0, 10.0] for _ in range(400)])
    assert abs(errs.std() - 0.2) < 0.02 and abs(errs.mean()) < 0.03
    with pytest.raises(ConfigError):
        _perception(world, noise_std=0.2)
    with pytest.raises(ConfigError):
        _perception(world, fov=0.0)


def test_3d_sensor_sees_spheres_within_its_vertical_fov():
    with PyBulletWorld(dims=3, arena_size=(20.0, 20.0, 10.0), mav_radius=0.5,
                       obstacle_radii=[0.8, 0.8]) as w:
        w.set_obstacle_positions([[15.0, 10.0, 7.0], [15.0, 10.0, 9.5]])   # +22 deg and +41 deg elevation
        grid = OccupancyGrid(np.zeros(3), np.array([20.0, 20.0, 10.0]), 1.0)
        perc = Perception(w, grid, fov_deg=90.0, range_m=8.0, resolution_deg=2.0, vfov_deg=60.0)
        det = perc.sense([10.0, 10.0, 5.0], 0.0)
        assert det.n_rays == 46 * 31
        assert det.ids.tolist() == [0] and np.allclose(det.centers, [[15.0, 10.0, 7.0]])
        assert grid.value_at(np.array([12.0, 10.0, 5.0])) == FREE
        det = perc.sense([10.0, 10.0, 8.0], 0.0)
        assert 1 in det.ids


def test_a_subprocess_sensing_prints_nothing_on_stdout():
    code = ("import numpy as np, sys\n"
            "from pbdyn.world.bullet import PyBulletWorld\n"
            "from pbdyn.perception.grid import OccupancyGrid\n"
            "from pbdyn.perception.perceive import Perception\n"
            "w = PyBulletWorld(dims=2, arena_size=(20, 20), mav_radius=0.5, obstacle_radii=[1.0])\n"
            "w.set_obstacle_positions([[14.0, 10.0]])\n"
            "p = Perception(w, OccupancyGrid([0, 0], [20, 20]), fov_deg=90, range_m=8, resolution_deg=1)\n"
            "print(p.sense([10.0, 10.0], 0.0).ids.tolist(), file=sys.stderr)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout == ""
    assert "[0]" in out.stderr
