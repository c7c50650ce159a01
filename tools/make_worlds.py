"""Write the imported-world set scenarios/worlds/imported_2d/*.toml (README "The study": the heterogeneous set).

    .venv/bin/python tools/make_worlds.py [--out scenarios/worlds/imported_2d] [--check]

Twelve 2D worlds of URDF bodies in four families, three worlds each, drawn from numpy Generators seeded by the
world's index (the files are committed; --check verifies that they are what this tool writes):
- warehouse: shelf rows (static boxes 2 m wide) with carts on waypoint loops through the aisles and carts crossing
  the floor at constant velocity;
- plaza: balls of mixed sizes (sphere.urdf) at constant velocity among a few pillars (pillar.urdf);
- office: static desks and cabinets of random size and heading, movers (boxes) on random waypoint loops;
- orbits: mesh bodies (urdf/gem.urdf) and balls circling fixed centres (pbdyn.world.motions:circle) among static
  mesh bodies.
Within a family the counts, sizes and speeds differ from world to world, so the set spans easy to hard worlds
that no (count, radius, speed) setup describes. Static bodies keep CLEARANCE_M between their bounding circle and
every start/goal candidate; everything stays inside the 50 x 50 m arena. The MAV flies at 4 m/s with the
heterogeneous_2d dataset's planner pairs, so the two pool (`pbdyn evaluate ... --pool`).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SIZE = 50.0
CANDIDATES = np.array([(x, y) for x in (4.0, 25.0, 46.0) for y in (4.0, 25.0, 46.0)])
CLEARANCE_M = 3.0
FAMILIES = ("warehouse", "plaza", "office", "orbits")
PER_FAMILY = 3
HEADER = '''# pbdyn imported world, written by tools/make_worlds.py (family "{family}", seed {seed}); do not edit by hand.
name = "{name}"

[world]
dims = 2
size = [50.0, 50.0]
time_limit = 80.0
flight_height = 2.0

[drone]
v_max = [4.0]

[[planners]]
trajectory = "local_primitives"
gaze = "lookahead"

[[planners]]
trajectory = "local_primitives"
gaze = "fullrange"
'''


def _num(x: float) -> str:
    return f"{float(x):.2f}"


def _vec(v) -> str:
    return "[" + ", ".join(_num(x) for x in v) + "]"


def _body(name: str, urdf: str, scale, **fields) -> str:
    lines = ["", "[[bodies]]", f'name = "{name}"', f'urdf = "{urdf}"',
             f"scale = {_vec(scale) if np.ndim(scale) else _num(scale)}"]
    for key, value in fields.items():
        if isinstance(value, str):
            lines.append(f'{key} = "{value}"')
        elif isinstance(value, dict):
            lines.append(f"{key} = {{ " + ", ".join(f"{k} = {_vec(v) if np.ndim(v) else _num(v)}"
                                                    for k, v in value.items()) + " }")
        elif np.ndim(value) == 2:
            lines.append(f"{key} = [" + ", ".join(_vec(p) for p in value) + "]")
        elif np.ndim(value) == 1:
            lines.append(f"{key} = {_vec(value)}")
        else:
            lines.append(f"{key} = {_num(value)}")
    return "\n".join(lines) + "\n"


def _clear_of_candidates(xy, reach: float) -> bool:
    """True when a static body's bounding circle (centre xy, radius reach) keeps CLEARANCE_M from every candidate
    and stays inside the arena."""
    xy = np.asarray(xy, float)
    inside = np.all(xy - reach >= 0.0) and np.all(xy + reach <= SIZE)
    return bool(inside and np.min(np.linalg.norm(CANDIDATES - xy, axis=1)) >= reach + CLEARANCE_M)


def _place(rng: np.random.Generator, reach: float, taken: list, gap: float = 1.0, tries: int = 500):
    """A centre for a static body of bounding radius ``reach``, clear of the candidates and of the bodies already
    placed (``taken``: (xy, reach)); None when none is found."""
    for _ in range(tries):
        xy = rng.uniform(reach, SIZE - reach, size=2)
        if _clear_of_candidates(xy, reach) and all(np.linalg.norm(xy - c) >= reach + r + gap for c, r in taken):
            return xy
    return None


def _statics(rng: np.random.Generator, count: int, draw, make) -> list[str]:
    """``count`` static bodies, each drawn by ``draw()`` -> (bounding radius, parameters) and placed by _place clear
    of the candidates and of each other (one that finds no place is left out); ``make(k, xy, parameters)`` writes
    body k at centre xy."""
    out, taken = [], []
    for k in range(count):
        reach, params = draw()
        xy = _place(rng, reach, taken)
        if xy is not None:
            taken.append((xy, reach))
            out.append(make(k, xy, params))
    return out


def _radius(rng: np.random.Generator, lo: float, hi: float):
    """A draw for _statics: a radius uniform in [lo, hi] m, as the bounding radius and as the body's parameter."""
    def draw():
        r = float(rng.uniform(lo, hi))
        return r, r
    return draw


def _heading_velocity(rng: np.random.Generator, speed: float) -> np.ndarray:
    a = rng.uniform(0.0, 2.0 * math.pi)
    return speed * np.array([math.cos(a), math.sin(a)])


def warehouse(rng: np.random.Generator) -> str:
    """Shelf rows with carts in the aisles: 2-4 shelf columns (two rows each), 3-8 carts at 1.5-4.5 m/s."""
    n_cols = int(rng.integers(2, 5))
    xs = np.linspace(12.0, 38.0, n_cols)
    length = float(rng.uniform(8.0, 12.0))
    out = []
    for i, x in enumerate(xs):
        for j, yc in enumerate((8.0 + length / 2.0, 42.0 - length / 2.0)):
            out.append(_body(f"shelf_{i}_{j}", "box.urdf", [2.0, length, 3.0], position=[x, yc, 1.5]))
    aisles = np.concatenate([[7.0], (xs[:-1] + xs[1:]) / 2.0, [43.0]])
    n_carts = int(rng.integers(3, 9))
    for k in range(n_carts):
        speed = float(rng.uniform(1.5, 4.5))
        if k % 3 == 2:                                   # a cart crossing the floor between the shelf rows
            y = float(rng.uniform(23.0, 27.0))
            vx = speed if rng.random() < 0.5 else -speed
            out.append(_body(f"cart_cross_{k}", "box.urdf", [1.6, 1.0, 1.2], position=[float(rng.uniform(8, 42)), y],
                             motion="constant_velocity", velocity=[vx, 0.0]))
        else:                                            # a loop up one aisle and down the next
            a = int(rng.integers(0, aisles.shape[0] - 1))
            x0, x1 = aisles[a], aisles[a + 1]
            y0, y1 = float(rng.uniform(5.0, 9.0)), float(rng.uniform(41.0, 45.0))
            loop = [[x0, y0], [x0, y1], [x1, y1], [x1, y0]]
            if rng.random() < 0.5:
                loop = loop[::-1]
            out.append(_body(f"cart_loop_{k}", "box.urdf", [1.0, 1.6, 1.2], motion="waypoints", waypoints=loop,
                             speed=speed))
    return "".join(out)


def plaza(rng: np.random.Generator) -> str:
    """8-25 balls of radius 0.4-1.8 m at 1-6 m/s among 0-4 pillars of radius 0.5-1.5 m."""
    out = _statics(rng, int(rng.integers(0, 5)), _radius(rng, 0.5, 1.5),
                   lambda k, xy, r: _body(f"pillar_{k}", "pillar.urdf", [r, r, 4.0], position=[*xy, 2.0]))
    for k in range(int(rng.integers(8, 26))):
        r = float(rng.uniform(0.4, 1.8))
        xy = rng.uniform(r, SIZE - r, size=2)
        out.append(_body(f"ball_{k}", "sphere.urdf", r, position=xy,
                         motion="constant_velocity", velocity=_heading_velocity(rng, float(rng.uniform(1.0, 6.0)))))
    return "".join(out)


def office(rng: np.random.Generator) -> str:
    """5-15 static desks/cabinets (0.8-6 m, any heading) and 4-10 movers on 2-4 point loops at 1-4 m/s."""
    def desk():
        w, d = float(rng.uniform(0.8, 6.0)), float(rng.uniform(0.8, 3.0))
        return 0.5 * math.hypot(w, d), (w, d)

    out = _statics(rng, int(rng.integers(5, 16)), desk,
                   lambda k, xy, wd: _body(f"desk_{k}", "box.urdf", [*wd, 2.5], position=[*xy, 1.25],
                                           rpy_deg=[0.0, 0.0, float(rng.uniform(0.0, 180.0))]))
    for k in range(int(rng.integers(4, 11))):
        n = int(rng.integers(2, 5))
        out.append(_body(f"mover_{k}", "box.urdf", [float(rng.uniform(0.6, 1.6)), float(rng.uniform(0.6, 1.6)), 1.8],
                         motion="waypoints", waypoints=rng.uniform(3.0, SIZE - 3.0, size=(n, 2)),
                         speed=float(rng.uniform(1.0, 4.0))))
    return "".join(out)


def orbits(rng: np.random.Generator) -> str:
    """2-6 static mesh bodies, 4-12 mesh bodies and balls circling centres (radius 2-9 m, 5-20 s per turn)."""
    out = _statics(rng, int(rng.integers(2, 7)), _radius(rng, 1.0, 2.5),
                   lambda k, xy, s: _body(f"gem_static_{k}", "../urdf/gem.urdf", s, position=[*xy, 2.0]))
    for k in range(int(rng.integers(4, 13))):
        radius = float(rng.uniform(2.0, 9.0))
        centre = rng.uniform(radius + 2.0, SIZE - radius - 2.0, size=2)
        params = {"center": [*centre, 2.0], "radius": radius, "period": float(rng.uniform(5.0, 20.0)),
                  "phase_deg": float(rng.uniform(0.0, 360.0))}
        if k % 2:
            out.append(_body(f"ball_orbit_{k}", "sphere.urdf", float(rng.uniform(0.5, 1.5)),
                             motion="pbdyn.world.motions:circle", params=params))
        else:
            out.append(_body(f"gem_orbit_{k}", "../urdf/gem.urdf", float(rng.uniform(0.8, 1.8)),
                             motion="pbdyn.world.motions:circle", params=params))
    return "".join(out)


BUILDERS = {"warehouse": warehouse, "plaza": plaza, "office": office, "orbits": orbits}


def worlds() -> dict[str, str]:
    """File name -> text of every world of the set."""
    out = {}
    for f, family in enumerate(FAMILIES):
        for i in range(PER_FAMILY):
            seed = 1000 + 10 * f + i
            name = f"{family}_{i}"
            text = HEADER.format(family=family, seed=seed, name=name)
            out[f"{name}.toml"] = text + BUILDERS[family](np.random.default_rng(seed))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=str(ROOT / "scenarios" / "worlds" / "imported_2d"))
    ap.add_argument("--check", action="store_true", help="verify the files instead of writing them")
    args = ap.parse_args(argv)
    out = Path(args.out)
    texts = worlds()
    if args.check:
        bad = [n for n, t in texts.items() if not (out / n).is_file() or (out / n).read_text() != t]
        if bad:
            print(f"make_worlds: {len(bad)} world file(s) differ from what this tool writes: {', '.join(bad)}",
                  file=sys.stderr)
            return 1
        print(f"make_worlds: {len(texts)} world files as written")
        return 0
    out.mkdir(parents=True, exist_ok=True)
    for n, t in texts.items():
        (out / n).write_text(t)
    print(f"make_worlds: wrote {len(texts)} worlds to {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
