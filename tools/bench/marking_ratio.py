"""Traversability under the thesis program's cell marking vs pbdyn's: ratio program / current per map.

For maps of scenarios/datasets/controlled_2d.toml (every ``--stride``-th map index, so every setup is covered),
computes traversability and dynamic traversability in grid mode with marking "centre_inside" (pbdyn) and
"program" (the thesis' program, pbdyn.metrics.traversability module doc), and for reference the default exact
mode (what compute_metrics reports). Prints per-setup and overall mean ratios (mean of per-map ratios, and ratio
of means).

    .venv/bin/python tools/bench/marking_ratio.py [--stride 20] [--limit N]
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from pbdyn.config import load_scenario  # noqa: E402
from pbdyn.metrics.traversability import dynamic_traversability, traversability  # noqa: E402
from pbdyn.world.maps import enumerate_maps  # noqa: E402
from pbdyn.world.rollout import build_rollout, default_horizon  # noqa: E402

VARIANTS = (("exact", dict(mode="exact")), ("grid", dict(mode="grid")),
            ("program", dict(mode="grid", marking="program")))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stride", type=int, default=20, help="every N-th map (20: one map per setup)")
    ap.add_argument("--offset", type=int, default=0)
    ap.add_argument("--limit", type=int, default=None)
    args = ap.parse_args()
    sc = load_scenario(ROOT / "scenarios" / "datasets" / "controlled_2d.toml")
    maps = list(enumerate_maps(sc))[args.offset::args.stride][: args.limit]
    rows = []
    for spec in maps:
        ro = build_rollout(sc, spec, default_horizon(sc))
        r = {"setup": spec.setup}
        for label, kw in VARIANTS:
            r[("T", label)] = traversability(ro, mav_radius=sc.drone.radius, **kw).value
            r[("D", label)] = dynamic_traversability(ro, mav_radius=sc.drone.radius, **kw).value
        rows.append(r)
        s = spec.setup
        print(f"map {spec.index:3d} n={s['count']:2d} r={s['radius']:.1f} v={s['speed']:.0f}  "
              + "  ".join(f"{m}:{lab}={r[(m, lab)]:6.3f}" for m in "TD" for lab, _ in VARIANTS), flush=True)
    for m, name in (("T", "traversability"), ("D", "dynamic traversability")):
        for ref in ("grid", "exact"):
            ratio = np.array([r[(m, "program")] / r[(m, ref)] for r in rows])
            means = np.mean([r[(m, "program")] for r in rows]) / np.mean([r[(m, ref)] for r in rows])
            print(f"{name:<24} program / {ref:<5}: mean of per-map ratios {ratio.mean():.4f} "
                  f"(min {ratio.min():.4f}, max {ratio.max():.4f}), ratio of means {means:.4f}, {len(rows)} maps")
        for rad in sorted({r["setup"]["radius"] for r in rows}):
            sel = [r for r in rows if r["setup"]["radius"] == rad]
            ratio = np.mean([r[(m, "program")] / r[(m, "grid")] for r in sel])
            print(f"    radius {rad:.1f}: program / grid {ratio:.4f} ({len(sel)} maps)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
