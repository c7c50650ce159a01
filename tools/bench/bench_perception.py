"""Benchmark of one perception scan: median ms of Perception.sense() per sensor configuration.

Configurations: 2D 90 deg and 360 deg fans (1 deg rays), 3D 90 x 60 deg and 360 x 60 deg grids (2 deg rays),
range 8 m, 1 m grid, 30 dynamic obstacles of radius 1 m in the default arena (50 x 50 m, 3D 50 x 50 x 20 m); the
same with the marching sensor (sensor.model = "marching": the thesis program's 50 rays per fan, 0.9 m steps).
Each call uses the next of ``--scenes`` random scenes (obstacle positions, MAV pose and yaw, drawn from one seeded
Generator); the grid persists between calls, as in a trial. Only sense() is timed. For reference the table also
shows the median time of the bare PyBullet ray test of the full fan (world.ray_test, every ray cast).

    .venv/bin/python tools/bench/bench_perception.py [--n 2000] [--scenes 200] [--obstacles 30] [--seed 1]
                                                     [--only SUBSTRING]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
from bench_common import machine as base_machine  # noqa: E402

from pbdyn.perception.grid import OccupancyGrid  # noqa: E402
from pbdyn.perception.perceive import Perception  # noqa: E402
from pbdyn.world.bullet import PyBulletWorld  # noqa: E402
from pbdyn.world.pybullet_client import pybullet  # noqa: E402

CONFIGS = (  # label, dims, fov_deg, resolution_deg, vfov_deg, sensor model, rays
    ("2D 90 deg, 1 deg", 2, 90.0, 1.0, None, "raycast", None),
    ("2D 360 deg, 1 deg", 2, 360.0, 1.0, None, "raycast", None),
    ("3D 90x60 deg, 2 deg", 3, 90.0, 2.0, 60.0, "raycast", None),
    ("3D 360x60 deg, 2 deg", 3, 360.0, 2.0, 60.0, "raycast", None),
    ("2D 90 deg, marching 50", 2, 90.0, 1.0, None, "marching", 50),
    ("2D 360 deg, marching 50", 2, 360.0, 1.0, None, "marching", 50),
    ("2D 90 deg, marching 1deg", 2, 90.0, 1.0, None, "marching", None),
    ("3D 90x60, marching 50", 3, 90.0, 2.0, 60.0, "marching", 50),
    ("3D 360x60, marching 50", 3, 360.0, 2.0, 60.0, "marching", 50),
)


def scenes(rng: np.random.Generator, size: np.ndarray, n_obstacles: int, radius: float, mav_radius: float,
           n: int) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """``n`` random (obstacle centres [N, d], MAV position [d], yaw) with the MAV clear of every obstacle."""
    out = []
    while len(out) < n:
        obs = rng.uniform(radius, size - radius, size=(n_obstacles, size.shape[0]))
        p = rng.uniform(2.0, size - 2.0)
        if np.all(np.linalg.norm(obs - p, axis=1) > radius + mav_radius):
            out.append((obs, p, float(rng.uniform(-np.pi, np.pi))))
    return out


def bench(label: str, dims: int, fov: float, res: float, vfov: float | None, model: str, rays: int | None,
          args) -> None:
    """Time sense() (and the bare full-fan ray test) over args.n calls and print one table row."""
    rng = np.random.default_rng(args.seed)
    size = np.array([50.0, 50.0] if dims == 2 else [50.0, 50.0, 20.0])
    radius, mav_radius = 1.0, 1.0
    world = PyBulletWorld(dims=dims, arena_size=size, mav_radius=mav_radius,
                          obstacle_radii=np.full(args.obstacles, radius))
    try:
        grid = OccupancyGrid(np.zeros(dims), size, 1.0)
        perc = Perception(world, grid, fov_deg=fov, range_m=8.0, resolution_deg=res, vfov_deg=vfov, model=model,
                          rays=rays)
        sc = scenes(rng, size, args.obstacles, radius, mav_radius, args.scenes)
        t_sense, t_rays, hits = [], [], []
        for i in range(args.n + args.warmup):
            obs, p, yaw = sc[i % len(sc)]
            world.set_obstacle_positions(obs)
            world.set_mav_pose(p, yaw)
            t0 = time.perf_counter()
            det = perc.sense(p, yaw)
            t1 = time.perf_counter()
            if i < args.warmup:
                continue
            t_sense.append(t1 - t0)
            hits.append(np.count_nonzero(det.hits >= 0) / det.n_rays)
            if i % 4 == 0:
                starts = np.tile(world.to_world3(p), (perc.n_rays, 1))
                ends = starts.copy()
                ends[:, :dims] += 8.0 * perc.directions(yaw)
                t2 = time.perf_counter()
                world.ray_test(starts, ends)
                t_rays.append(time.perf_counter() - t2)
        ms = 1000.0 * np.asarray(t_sense)
        print(f"{label:<22} {perc.n_rays:>5} {np.median(ms):9.3f} {np.percentile(ms, 10):8.3f} "
              f"{np.percentile(ms, 90):8.3f} {1000.0 * np.median(t_rays):12.3f} {100.0 * np.mean(hits):7.1f}%")
    finally:
        world.close()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=2000, help="timed sense() calls per configuration (>= 1000)")
    ap.add_argument("--warmup", type=int, default=50)
    ap.add_argument("--scenes", type=int, default=200, help="random scenes cycled through")
    ap.add_argument("--obstacles", type=int, default=30)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--only", default="", help="run only configurations whose label contains this")
    args = ap.parse_args()
    print((base_machine() + f", pybullet API={pybullet.getAPIVersion()}"))
    print(f"{'configuration':<22} {'rays':>5} {'median ms':>9} {'p10 ms':>8} {'p90 ms':>8} "
          f"{'ray_test ms':>12} {'hit':>8}")
    for label, dims, fov, res, vfov, model, rays in CONFIGS:
        if args.only in label:
            bench(label, dims, fov, res, vfov, model, rays, args)
    print("median/p10/p90: Perception.sense(); ray_test: median of the bare full-fan world.ray_test (every 4th call); "
          "hit: mean fraction of rays that hit a body.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
