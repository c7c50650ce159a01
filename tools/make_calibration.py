"""Write the frozen calibration sets of the anchored difficulty scale (pbdyn.analysis.scale): scenarios/calibration/.

Each set lists explicit maps ([[obstacles.maps]]): for every generator family (pbdyn's built-in structures), MAPS
maps whose (n, r, v) come from a seeded Latin hypercube over the thesis' box (n in [10, 30], r in [0.5, 1.5] m,
v in [2, 6] m/s; eqs. 5-4 to 5-6), so that the set spans easy to hard maps of every family. The experiment is the
reference panel's flights (pbdyn.analysis.scale.reference_document): `pbdyn batch` on a set flies exactly what
`pbdyn calibrate` flies on those maps.

    .venv/bin/python tools/make_calibration.py            # (re)write scenarios/calibration/calibration_{2d,3d}.toml
    .venv/bin/python tools/make_calibration.py --check    # exit 1 if a written file differs from what this gives
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from pbdyn.config import BUILTIN_STRUCTURES, parse_scenario  # noqa: E402
from pbdyn.analysis.scale import reference_document  # noqa: E402

MAPS = 8
SEED = 2026
BOX = {"count": (10, 30), "radius": (0.5, 1.5), "speed": (2.0, 6.0)}


def latin_hypercube(rng: np.random.Generator, n: int) -> dict[str, list]:
    """n points of a Latin hypercube over BOX (each field's range cut into n strata, one point in each)."""
    out = {}
    for key, (lo, hi) in BOX.items():
        u = (rng.permutation(n) + rng.uniform(size=n)) / n
        vals = lo + u * (hi - lo)
        out[key] = [int(round(x)) for x in vals] if key == "count" else [round(float(x), 2) for x in vals]
    return out


def document(dims: int) -> dict:
    """The calibration set of ``dims`` D as a scenario document."""
    maps = []
    for f, family in enumerate(BUILTIN_STRUCTURES):
        rng = np.random.default_rng([SEED, dims, f])
        pts = latin_hypercube(rng, MAPS)
        for k in range(MAPS):
            maps.append({"count": pts["count"][k], "radius": pts["radius"][k], "speed": pts["speed"][k],
                         "structure": family, "replicate": k})
    base = {"name": f"calibration_{dims}d", "world": {"dims": dims, "time_limit": 80.0},
            "obstacles": {"root_seed": SEED, "maps": maps}}
    sc = parse_scenario(base)
    doc = reference_document(base, sc.task.candidates)
    from pbdyn.world.maps import enumerate_maps

    for entry, spec in zip(doc["obstacles"]["maps"], enumerate_maps(parse_scenario(doc))):
        entry["seed"] = spec.seed
    return doc


HEADER = """pbdyn calibration set {dims}D of the anchored difficulty scale (pbdyn.analysis.scale;
docs/difficulty-scale.md), written by tools/make_calibration.py: do not edit by hand (the shipped abilities were fitted on
these maps). {n} maps: {per} per generator family, (n, r, v) from a seeded Latin hypercube over the thesis' box.
The experiment is the reference panel's flights: pbdyn batch on this file flies what pbdyn calibrate flies."""


def main(argv=None) -> int:
    import tomli_w

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="compare with the written files instead of writing")
    args = ap.parse_args(argv)
    bad = 0
    for dims in (2, 3):
        doc = document(dims)
        text = "".join(f"# {line}\n" for line in HEADER.format(dims=dims, n=len(doc["obstacles"]["maps"]),
                                                                per=MAPS).splitlines()) + tomli_w.dumps(doc)
        path = ROOT / "scenarios" / "calibration" / f"calibration_{dims}d.toml"
        if args.check:
            if not path.is_file() or path.read_text() != text:
                print(f"{path.relative_to(ROOT)} differs from what tools/make_calibration.py writes")
                bad += 1
        else:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(text)
            print(f"wrote {path.relative_to(ROOT)} ({len(doc['obstacles']['maps'])} maps)")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
