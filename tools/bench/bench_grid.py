"""Occupancy-grid clearance queries (OccupancyGrid.collides, the planners' static check): median time per call of this
checkout, and of an older revision's grid module for comparison (same queries, results compared bit for bit).

Configurations: a 2D 50 x 50 m and a 3D 50 x 50 x 20 m grid (1 m cells) with two walls across the arena (0.5 m
thick, full height in 3D, one 4 m gap each) whose cells are OCCUPIED as a MAV's rays would leave them, plus 1% random
OCCUPIED cells; queries: the candidate end points of local primitives (72 in 2D, 400 in 3D) and a candidate chunk's
samples (24 candidates x 10 samples), at points near the walls (within 4 m) and anywhere, MAV radius 1 m + 0.5 m
margin. numpy Generator seed 0.

    .venv/bin/python tools/bench/bench_grid.py [--ref REV] [--repeat 200]
"""

from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from pbdyn.perception.grid import OCCUPIED, OccupancyGrid  # noqa: E402


def _old_grid_class(rev: str):
    """OccupancyGrid from pbdyn/perception/grid.py at git revision ``rev``."""
    src = subprocess.run(["git", "show", f"{rev}:pbdyn/perception/grid.py"], cwd=ROOT, capture_output=True,
                         text=True, check=True).stdout
    path = Path(tempfile.mkdtemp()) / "old_grid.py"
    path.write_text(src)
    spec = importlib.util.spec_from_file_location("old_grid", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.OccupancyGrid


def _world(cls, dims: int, rng: np.random.Generator):
    size = np.array([50.0, 50.0, 20.0][:dims])
    g = cls(np.zeros(dims), size, 1.0)
    g.cells[rng.random(g.shape) < 0.01] = OCCUPIED
    for y, gap in ((17.0, 12.0), (33.0, 36.0)):           # two walls across x, each with a 4 m gap
        for x in np.arange(0.25, 50.0, 0.5):
            if abs(x - gap) < 2.0:
                continue
            pts = np.array([[x, y]]) if dims == 2 else np.array([[x, y, z] for z in np.arange(0.5, 20.0, 1.0)])
            g.mark_occupied(pts)
    return g


def _queries(dims: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    lo, hi = np.zeros(dims), np.array([50.0, 50.0, 20.0][:dims])
    n_end = 72 if dims == 2 else 400
    near = rng.uniform(lo, hi, size=(4000, dims))
    near[:, 1] = np.where(rng.random(4000) < 0.5, 17.0, 33.0) + rng.uniform(-4.0, 4.0, 4000)
    return {"end points near walls": near[:n_end], "end points anywhere": rng.uniform(lo, hi, size=(n_end, dims)),
            "chunk samples near walls": near[:240], "chunk samples anywhere": rng.uniform(lo, hi, size=(240, dims))}


def _median_us(g, pts: np.ndarray, repeat: int) -> tuple[float, np.ndarray]:
    out = g.collides(pts, 1.5)
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        g.collides(pts, 1.5)
        times.append(time.perf_counter() - t0)
    return float(np.median(times) * 1e6), out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ref", help="git revision whose grid module is timed beside this checkout's")
    ap.add_argument("--repeat", type=int, default=200)
    args = ap.parse_args(argv)
    old_cls = _old_grid_class(args.ref) if args.ref else None
    print(f"{'configuration':<34} {'new [us]':>9}" + (f" {'old [us]':>9} {'old/new':>8}" if old_cls else ""))
    for dims in (2, 3):
        grids = [_world(OccupancyGrid, dims, np.random.default_rng(0))]
        if old_cls is not None:
            grids.append(_world(old_cls, dims, np.random.default_rng(0)))
        for name, pts in _queries(dims, np.random.default_rng(1)).items():
            t_new, r_new = _median_us(grids[0], pts, args.repeat)
            line = f"{dims}D {name:<31} {t_new:>9.1f}"
            if old_cls is not None:
                t_old, r_old = _median_us(grids[1], pts, args.repeat)
                if not np.array_equal(r_new, r_old):
                    print(f"results differ: {dims}D {name}", file=sys.stderr)
                    return 1
                line += f" {t_old:>9.1f} {t_old / t_new:>8.2f}"
            print(line + f"   ({pts.shape[0]} points)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
