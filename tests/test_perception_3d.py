"""3D perception in real PyBullet worlds: the depth-camera ray grid, occlusion, the voxel grid, FullRange, agreement
with in_fov, ray culling equal to casting every ray, and the vectorised free-space marking equal to a per-ray loop."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pbdyn.perception.grid import FREE, OCCUPIED, UNKNOWN, OccupancyGrid
from pbdyn.perception.perceive import Perception
from pbdyn.perception.sensor import in_fov, ray_directions
from pbdyn.world.bullet import PyBulletWorld
from pbdyn.world.geometry import StaticBody
from pbdyn.world.pybullet_client import pybullet

ARENA3 = (20.0, 20.0, 10.0)
MAV = np.array([5.0, 10.0, 5.0])
FAR = [-500.0, -500.0, -500.0]          # outside the arena: no ray reaches it


def _world3(radii, static=()):
    return PyBulletWorld(dims=3, arena_size=ARENA3, mav_radius=0.3, obstacle_radii=radii, static_bodies=static)


def _perception3(world, fov=90.0, vfov=60.0, res=1.0):
    grid = OccupancyGrid(np.zeros(3), np.asarray(ARENA3), res)
    return Perception(world, grid, fov_deg=fov, range_m=8.0, resolution_deg=2.0, vfov_deg=vfov), grid


def _at_angles(origin, yaw, az_deg, el_deg, dist):
    """The point at ``dist`` (m) from origin, azimuth az_deg relative to yaw and elevation el_deg."""
    a, e = yaw + math.radians(az_deg), math.radians(el_deg)
    return origin + dist * np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])


# ------------------------------------------------------------------------------------------ the ray grid
def test_sphere_in_the_frustum_is_seen_and_spheres_outside_the_window_are_not():
    ahead = _at_angles(MAV, 0.0, 0.0, 0.0, 5.0)
    above = _at_angles(MAV, 0.0, 0.0, 40.0, 6.0)      # radius 0.5 spans 40 +- 4.8 deg: above the 30 deg edge
    aside = _at_angles(MAV, 0.0, 60.0, 0.0, 5.0)      # azimuth 60 +- 5.7 deg: beside the 45 deg edge
    with _world3([0.5, 0.5, 0.5]) as w:
        w.set_obstacle_positions([ahead, above, aside])
        w.set_mav_pose(MAV, 0.0)
        perc, _ = _perception3(w)
        det = perc.sense(MAV, 0.0)
        assert det.n_rays == 46 * 31 and det.ids.tolist() == [0]
        assert np.allclose(det.centers, [ahead])
        assert in_fov(0.0, np.array([ahead, above, aside]) - MAV, 90.0, 8.0, vfov_deg=60.0).tolist() == [
            True, False, False]
        assert perc.sense(MAV, math.radians(60.0)).ids.tolist() == [2]       # the grid turns with the yaw
        tall, _ = _perception3(w, vfov=90.0)                                   # a +-45 deg window reaches it
        assert tall.sense(MAV, 0.0).ids.tolist() == [0, 1]


def test_occlusion_by_a_sphere_and_by_a_static_box():
    box = StaticBody("box", (5.0, 6.0, 5.0), size=(3.0, 0.5, 3.0))        # a slab 4 m to the MAV's right (-y)
    with _world3([1.0, 0.4, 0.4], static=[box]) as w:
        front, behind, hidden = [8.0, 10.0, 5.0], [12.0, 10.0, 5.0], [5.0, 3.0, 5.0]
        w.set_obstacle_positions([front, behind, hidden])
        w.set_mav_pose(MAV, 0.0)
        perc, grid = _perception3(w)
        assert perc.sense(MAV, 0.0).ids.tolist() == [0]                      # 1 sits behind 0
        det = perc.sense(MAV, -math.pi / 2)                                    # 2 sits behind the box
        assert 2 not in det.ids.tolist()
        assert grid.value_at(np.array([5.0, 3.0, 5.0])) == UNKNOWN
        w.set_obstacle_positions([FAR, behind, [8.5, 4.0, 5.0]])            # clear sight lines to both
        assert perc.sense(MAV, 0.0).ids.tolist() == [1]
        assert perc.sense(MAV, -math.pi / 2).ids.tolist() == [2]


def test_full_range_3d_sees_a_sphere_behind_the_mav():
    with _world3([0.5, 0.5]) as w:
        w.set_obstacle_positions([[1.5, 10.0, 5.0], _at_angles(MAV, 0.0, 120.0, 20.0, 5.0)])
        w.set_mav_pose(MAV, 0.0)
        narrow, _ = _perception3(w)
        assert narrow.sense(MAV, 0.0).ids.tolist() == []
        full, _ = _perception3(w, fov=360.0)
        det = full.sense(MAV, 0.0)
        assert det.n_rays == 180 * 31 and det.ids.tolist() == [0, 1]


def test_the_voxel_grid_frees_cells_along_rays_and_occupies_static_hits():
    wall = StaticBody("box", (11.0, 10.0, 5.0), size=(1.0, 6.0, 6.0))      # its near face at x = 10.5
    with _world3([0.8], static=[wall]) as w:
        w.set_obstacle_positions([FAR])
        w.set_mav_pose(MAV, 0.0)
        perc, grid = _perception3(w)
        assert np.all(grid.cells == UNKNOWN)
        v0 = grid.version
        perc.sense(MAV, 0.0)
        on_axis = np.array([[x, 10.5, 5.5] for x in (5.5, 6.5, 7.5, 8.5, 9.5)])
        assert grid.value_at(on_axis).tolist() == [FREE] * 5
        assert grid.value_at(np.array([10.6, 10.2, 5.2])) == OCCUPIED                 # the cell behind the face
        assert grid.value_at(np.array([12.5, 10.5, 5.5])) == UNKNOWN                  # inside / behind the box
        assert grid.value_at(np.array([3.5, 10.5, 5.5])) == UNKNOWN                   # behind the MAV
        assert grid.value_at(np.array([8.5, 10.5, 8.9])) == UNKNOWN                   # above the 30 deg window
        assert grid.version > v0
        occupied = grid.cell_center(np.argwhere(grid.cells == OCCUPIED))
        assert occupied.shape[0] > 10 and np.all(np.abs(occupied[:, 0] - 10.5) < 1.0)  # only the face's cells
        # A dynamic sphere: free up to its surface, never mapped, the space behind it stays unknown.
        grid2 = OccupancyGrid(np.zeros(3), np.asarray(ARENA3), 1.0)
        perc2 = Perception(w, grid2, fov_deg=90.0, range_m=8.0, resolution_deg=2.0, vfov_deg=60.0)
        w.set_obstacle_positions([[8.5, 10.5, 5.5]])
        assert perc2.sense(MAV, 0.0).ids.tolist() == [0]
        assert grid2.value_at(np.array([6.5, 10.5, 5.5])) == FREE
        assert grid2.value_at(np.array([9.5, 10.5, 5.5])) == UNKNOWN                  # behind the sphere's front
        assert not np.any(grid2.value_at(np.array([[8.5, 10.5, 5.5], [8.0, 10.5, 5.5]])) == OCCUPIED)


def _min_angle_to_rays(dirs, u):
    return math.degrees(math.acos(min(1.0, float(np.max(dirs @ u)))))


def test_in_fov_agrees_with_the_ray_grid_for_random_spheres():
    rng = np.random.default_rng(3)
    r = 0.6
    inside = outside = 0
    with _world3([r]) as w:
        perc, _ = _perception3(w)
        for _ in range(300):
            o = rng.uniform([8.0, 8.0, 4.0], [12.0, 12.0, 6.0])
            yaw = rng.uniform(-math.pi, math.pi)
            dist = rng.uniform(1.5, 10.0)
            c = _at_angles(o, yaw, rng.uniform(-110.0, 110.0), rng.uniform(-55.0, 55.0), dist)
            if np.any(c < r) or np.any(c > np.asarray(ARENA3) - r):
                continue
            w.set_obstacle_positions([c])
            w.set_mav_pose(o, yaw)
            covered = bool(in_fov(yaw, c - o, 90.0, 8.0, vfov_deg=60.0)[0])
            alpha = math.degrees(math.asin(r / dist))
            gap = _min_angle_to_rays(perc.directions(yaw), (c - o) / dist)
            if covered and dist <= 7.0:                      # well inside: some ray passes within 1.5 deg of it
                inside += 1
                assert perc.sense(o, yaw).ids.tolist() == [0], (o, yaw, c)
            elif not covered and (gap > alpha + 0.5 or dist - r > 8.1):     # well outside the window or range
                outside += 1
                assert perc.sense(o, yaw).ids.tolist() == [], (o, yaw, c)
    assert inside >= 30 and outside >= 60


# ------------------------------------------------------------------------------------------ ray culling
def _grazing_scene(rng, dims, size, dirs, n):
    """Obstacle centres [n, dims] placed so the given rays pass within +-2 mm of their surfaces (radius 1 m)."""
    o = rng.uniform(1.0, size - 1.0)
    centres = []
    for k in rng.choice(dirs.shape[0], n, replace=False):
        u = dirs[k]
        side = rng.normal(size=dims)
        side -= (side @ u) * u
        side /= np.linalg.norm(side)
        centres.append(o + rng.uniform(1.5, 8.5) * u + (1.0 + rng.choice([-2e-3, 2e-3])) * side)
    return o, np.array(centres)


@pytest.mark.parametrize("dims", [2, 3])
def test_culled_ray_casting_equals_casting_every_ray(dims):
    rng = np.random.default_rng(dims)
    size = np.array([24.0, 16.0] if dims == 2 else [24.0, 16.0, 10.0])
    statics = [StaticBody("pillar", (6.0, 8.0), radius=0.7),
               StaticBody("box", (16.0, 5.0, 5.0)[:dims], size=(2.0, 1.0, 3.0)[:dims], yaw=0.5),
               StaticBody("box", (12.0, 14.5, 5.0)[:dims], size=(8.0, 0.3, 3.0)[:dims])]     # a long thin slab
    with PyBulletWorld(dims=dims, arena_size=size, mav_radius=0.3, obstacle_radii=np.ones(12),
                       static_bodies=statics) as w:
        for trial in range(40):
            yaw = rng.uniform(-math.pi, math.pi)
            dirs = ray_directions(yaw, 360.0 if trial % 2 else 90.0, 1.0 if dims == 2 else 3.0, dims,
                                  60.0, 3.0)
            if trial % 4 == 0:                               # outside the arena: rays hit the walls' outer faces
                o, centres = rng.uniform(-0.5, size + 0.5), rng.uniform(0.0, size, (12, dims))
                o[trial % dims] = -1.5 if trial % 8 == 0 else size[trial % dims] + 1.5
            else:
                o, centres = _grazing_scene(rng, dims, size, dirs, 12)
                if trial % 4 == 1:                            # the sensor inside obstacle 0 (and near another)
                    centres[0] = o + 0.5 * dirs[0]
                    centres[1] = o + 1.02 * dirs[-1]
                if trial % 8 == 3:                            # beside the slab, within its bounding sphere
                    o = np.array([9.0, 15.1, 5.0])[:dims]
            w.set_obstacle_positions(centres)
            ids, frac = w.cast_fan(o, dirs, 8.0)
            all_ids, all_frac = w.cast_fan(o, dirs, 8.0, cull=False)
            starts = np.tile(w.to_world3(o), (dirs.shape[0], 1))
            ends = starts.copy()
            ends[:, :dims] += 8.0 * dirs
            ref_ids, ref_frac, _ = w.ray_test(starts, ends)
            assert np.array_equal(ids, ref_ids) and np.array_equal(frac, ref_frac)
            assert np.array_equal(all_ids, ref_ids) and np.array_equal(all_frac, ref_frac)
        # Nothing within reach: no ray is sent to Bullet; one sphere ahead: only the rays towards it are.
        far = np.full((12, dims), -50.0)
        w.set_obstacle_positions(far)
        centre = 0.5 * size
        centre[0] = 11.0
        fan = ray_directions(0.0, 360.0, 1.0, dims, 60.0, 3.0)
        assert not w.fan_candidates(centre, fan, 4.0).any()
        far[0] = centre + 3.0 * np.eye(dims)[0]
        w.set_obstacle_positions(far)
        kept = w.fan_candidates(centre, fan, 4.0)
        assert 0 < np.count_nonzero(kept) < 0.15 * fan.shape[0]
        assert np.all(fan[kept, 0] > 0.9) and np.all(w.cast_fan(centre, fan, 4.0)[0][~kept] == -1)
        # A body created in the client behind the world's back: culling is switched off, Bullet still sees it.
        w.set_obstacle_positions(np.full((12, dims), -50.0))
        shape = w.client.createCollisionShape(pybullet.GEOM_SPHERE, radius=0.5)
        extra = w.client.createMultiBody(0.0, shape, basePosition=w.to_world3(centre + np.eye(dims)[0]))
        ids, _ = w.cast_fan(centre, ray_directions(0.0, 90.0, 1.0, dims, 60.0, 3.0), 2.0)
        assert extra in ids.tolist()


# ------------------------------------------------------------------------------------------ free space
def free_cells_reference(grid, o, dirs, reach, range_m):
    """The reference twin of Perception.free_cells, a per-ray loop: the flat cells of the samples at
    min(t_j, reach - 1e-9 res), t_j = j range / n, n = ceil(4 range / res) (m)."""
    res = grid.res
    n = int(math.ceil(range_m / (res / 4.0)))
    t_cells = np.linspace(0.0, range_m, n + 1) / res
    oc = (o - grid.origin) * (1.0 / res)
    cells = set()
    for r in range(dirs.shape[0]):
        lim = reach[r] * (1.0 / res) - 1e-9
        for t in t_cells.tolist():
            dist = min(t, lim)
            idx = [min(max(math.floor(float(dirs[r, k]) * dist + float(oc[k])), 0), grid.shape[k] - 1)
                   for k in range(grid.dims)]
            cells.add(int(np.ravel_multi_index(idx, grid.shape)))
    return np.array(sorted(cells), dtype=np.int64)


@pytest.mark.parametrize("dims,res", [(2, 1.0), (2, 0.7), (3, 1.0), (3, 0.7)])
def test_vectorised_free_marking_equals_a_per_ray_reference(dims, res):
    rng = np.random.default_rng(10 * dims + int(10 * res))
    size = np.array([20.0, 14.0] if dims == 2 else [20.0, 14.0, 9.0])
    statics = [StaticBody("box", (12.0, 7.0, 4.5)[:dims] if dims == 3 else (12.0, 7.0), size=(1.5, 3.0, 2.0)[:dims],
                          yaw=0.3)]
    with PyBulletWorld(dims=dims, arena_size=size, mav_radius=0.3, obstacle_radii=rng.uniform(0.4, 1.2, 10),
                       static_bodies=statics) as w:
        grid = OccupancyGrid(np.zeros(dims), size, res)
        perc = Perception(w, grid, fov_deg=360.0 if dims == 2 else 90.0, range_m=8.0, resolution_deg=4.0,
                          vfov_deg=60.0 if dims == 3 else None)
        expected = np.full(grid.cells.size, UNKNOWN)
        for k in range(6):
            w.set_obstacle_positions(rng.uniform(0.5, size - 0.5, (10, dims)))
            o = rng.uniform(0.6, size - 0.6) if k % 2 else rng.uniform(3.0, size - 3.0)
            if k == 4:
                o[0] = -1.5                 # outside the walls: samples leave the grid and are clipped into it
            if k == 5:
                o[1] = size[1] + 1.5        # beyond the far wall: clipped at the grid's top cells
            yaw = rng.uniform(-math.pi, math.pi)
            w.set_mav_pose(o, yaw)
            det = perc.sense(o, yaw)
            reach = np.where(det.hits >= 0, det.ranges, np.inf)
            dirs = perc.directions(yaw)
            ref = free_cells_reference(grid, o, dirs, reach, 8.0)
            assert np.array_equal(perc.free_cells(o, dirs.T, reach), ref)
            static = w.is_static_body[det.hits]
            occ = grid.flat_index(o + dirs[static] * (det.ranges[static] + 1e-3)[:, None])
            expected[ref[expected[ref] != OCCUPIED]] = FREE
            expected[occ] = OCCUPIED
            assert np.array_equal(grid.cells.reshape(-1), expected)
            assert k < 2 or np.any(expected == OCCUPIED)


@pytest.mark.parametrize("dims", [2, 3])
def test_compiled_scan_completion_equals_numpy(dims):
    """Perception.complete (compiled) leaves the grid, its version and the detections exactly as its reference twin
    _complete_reference does, scan after scan, with walls, static boxes and obstacles hit and the sensor outside the
    arena once."""
    rng = np.random.default_rng(40 + dims)
    size = np.array([20.0, 14.0] if dims == 2 else [20.0, 14.0, 9.0])
    statics = [StaticBody("box", (12.0, 7.0, 4.5)[:dims] if dims == 3 else (12.0, 7.0), size=(1.5, 3.0, 2.0)[:dims],
                          yaw=0.3)]
    with PyBulletWorld(dims=dims, arena_size=size, mav_radius=0.3, obstacle_radii=rng.uniform(0.4, 1.2, 10),
                       static_bodies=statics) as w:
        grids = [OccupancyGrid(np.zeros(dims), size, 0.7) for _ in range(2)]
        percs = [Perception(w, g, fov_deg=360.0 if dims == 2 else 90.0, range_m=8.0, resolution_deg=4.0,
                            vfov_deg=60.0 if dims == 3 else None) for g in grids]
        kinds = set()
        for k in range(8):
            w.set_obstacle_positions(rng.uniform(0.5, size - 0.5, (10, dims)))
            o = rng.uniform(0.6, size - 0.6)
            if k == 5:
                o[0] = -1.5
            yaw = rng.uniform(-math.pi, math.pi)
            w.set_mav_pose(o, yaw)
            scan = percs[0].begin(o, yaw)
            hits, frac = w.cast_fan_rays(scan.fan)
            got = percs[0].complete(scan, hits, frac)
            want = percs[1]._complete_reference(scan, hits, frac)
            assert np.array_equal(grids[0].cells, grids[1].cells) and grids[0].version == grids[1].version
            assert np.array_equal(got.ids, want.ids) and got.ids.dtype == want.ids.dtype
            assert np.array_equal(got.centers, want.centers) and np.array_equal(got.ranges, want.ranges)
            kinds.update(("static" if w.is_static_body[h] else "obstacle" if w.dynamic_index_of[h] >= 0 else "none")
                         for h in hits.tolist())
        assert kinds == {"static", "obstacle", "none"} and grids[0].version > 0


def test_grid_cell_level_marking():
    g = OccupancyGrid([0, 0, 0], [6, 5, 4], 0.5)
    pts = np.random.default_rng(1).uniform(-1.0, 7.0, (50, 3))
    assert np.array_equal(g.flat_index(pts), np.ravel_multi_index(tuple(g.index(pts).T), g.shape))
    g.mark_occupied_cells([3, 7])
    assert g.version == 1
    g.mark_occupied_cells([7])
    assert g.version == 1                               # nothing new
    g.mark_free_cells(np.array([1, 3, 7, 9, 9]))
    flat = g.cells.reshape(-1)
    assert flat[[1, 9]].tolist() == [FREE, FREE] and flat[[3, 7]].tolist() == [OCCUPIED, OCCUPIED]
    assert g.discovered() == 4


@pytest.mark.parametrize("dims", [2, 3])
def test_fans_culled_together_cast_as_every_ray(dims):
    """Lockstep trials cull their fans together (fan_rays_many; cast_fans_many, which lockstep uses, gives the same
    hits): every fan's hits equal casting all its rays, walls, static boxes and grazed obstacles included, and the
    kept rays equal fan_candidates' one fan at a time."""
    rng = np.random.default_rng(10 + dims)
    size = np.array([24.0, 16.0] if dims == 2 else [24.0, 16.0, 10.0])
    statics = [StaticBody("pillar", (6.0, 8.0), radius=0.7),
               StaticBody("box", (16.0, 5.0, 5.0)[:dims], size=(2.0, 1.0, 3.0)[:dims], yaw=0.5),
               StaticBody("box", (12.0, 14.5, 5.0)[:dims], size=(8.0, 0.3, 3.0)[:dims])]
    same = total = 0
    with PyBulletWorld(dims=dims, arena_size=size, mav_radius=0.3, obstacle_radii=np.ones(12),
                       static_bodies=statics) as w:
        for scene in range(12):
            yaws = rng.uniform(-math.pi, math.pi, 6)
            fans = [ray_directions(y, 90.0, 1.0 if dims == 2 else 3.0, dims, 60.0, 3.0) for y in yaws]
            o0, centres = _grazing_scene(rng, dims, size, fans[0], 12)
            origins = np.array([o0] + [rng.uniform(-0.5, size + 0.5) for _ in range(5)])
            origins[1] = [9.0, 15.1, 5.0][:dims]                     # beside the slab
            w.set_obstacle_positions(centres)
            made = w.fan_rays_many(origins, np.array([f.T for f in fans]), 8.0)
            many_ids, many_frac = w.cast_fans_many(origins, np.array([f.T for f in fans]), 8.0)
            for k, ((ids, frac), o, fan, rays) in enumerate(zip(w.cast_fans(made), origins, fans, made)):
                assert np.array_equal(many_ids[k], ids) and np.array_equal(many_frac[k], frac)
                starts = np.tile(w.to_world3(o), (fan.shape[0], 1))
                ends = starts.copy()
                ends[:, :dims] += 8.0 * fan
                ref_ids, ref_frac, _ = w.ray_test(starts, ends)
                assert np.array_equal(ids, ref_ids) and np.array_equal(frac, ref_frac)
                single = w.fan_rays(o, fan, 8.0)
                kept = np.arange(fan.shape[0]) if rays.selected is None else rays.selected
                one = np.arange(fan.shape[0]) if single.selected is None else single.selected
                same += int(np.array_equal(kept, one))
                total += 1
                assert np.array_equal(rays.starts, single.starts) or not np.array_equal(kept, one)
                assert np.array_equal(rays.ends, single.ends) or not np.array_equal(kept, one)
    assert same == total
