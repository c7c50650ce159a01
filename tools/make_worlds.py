"""Write the imported-world sets scenarios/worlds/imported_2d/*.toml (docs/science.md: the heterogeneous set)
and scenarios/worlds/imported_3d/*.toml.

    .venv/bin/python tools/make_worlds.py [--dims {2,3}] [--out DIR (with --dims)] [--check]

Without --dims both sets are written (or, with --check, both are verified: the files are committed, and --check
exits 1 when one differs from what this tool writes). Every world is drawn from a numpy Generator seeded by the
world's index: 1000 + 10 f + i for world i of 2D family f, SEED_3D + 10 f + i in 3D (so neither set changes the
other).

Twelve 2D worlds of URDF bodies in four families, three worlds each:
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

Nine 3D worlds (50 x 50 x 20 m, time limit 80 s) in three families, three worlds each; world 0 of a family is
easy, world 1 medium, world 2 hard (3-7 times world 0's movers, larger; SPEEDS_3D: 1-2.5, 2-4 and 3-6 m/s):
- hangar: rack columns of box racks standing on the floor and stacked up to three high, shuttles (boxes) on
  waypoint loops up one aisle and down the next that change height on the way, and carts crossing between the
  rack rows at constant velocity;
- atrium: floor-to-ceiling pillars (pillar.urdf) and balls of mixed sizes (sphere.urdf) at constant velocity in
  any heading, up to 40 deg up or down;
- orbits: static mesh bodies anywhere in the volume, mesh bodies and balls circling fixed centres at every height
  (motions:circle, whose circles are horizontal: there is no tilted one) and balls bobbing up and down
  (motions:bob).
The start/goal candidates are pbdyn's 3D default, the 2D grid at z = 10 m (CANDIDATES_3D). A static body keeps
CLEARANCE_M from every candidate with its bounding sphere or, where that is closer (a tall rack or pillar), with
its bounding vertical cylinder (both enclose the body); every body stays inside the arena. The files carry
drone.v_max = [2, 4, 6] (the reference panel's speeds: `pbdyn calibrate` flies them) and the 2D set's planner
pairs.
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


# ------------------------------------------------------------------------------------------------ 3D worlds
SIZE_3D = np.array([50.0, 50.0, 20.0])
CANDIDATES_3D = np.array([(x, y, 10.0) for x in (4.0, 25.0, 46.0) for y in (4.0, 25.0, 46.0)])
"""The default start/goal candidates of the 50 x 50 x 20 m world (pbdyn.config.default_candidates: the 2D grid at
half the height)."""
FAMILIES_3D = ("hangar", "atrium", "orbits")
SEED_3D = 3000
"""World i of 3D family f is drawn from default_rng(SEED_3D + 10 f + i) (the 2D set's seeds are 1000 + 10 f + i)."""
SPEEDS_3D = ((1.0, 2.5), (2.0, 4.0), (3.0, 6.0))
"""Speed ranges (m/s) of the moving bodies of world 0 (easy), 1 and 2 (hard) of every 3D family."""
HEADER_3D = '''# pbdyn imported world, written by tools/make_worlds.py (family "{family}", seed {seed}); do not edit by hand.
name = "{name}"

[world]
dims = 3
size = [50.0, 50.0, 20.0]
time_limit = 80.0

[drone]
v_max = [2.0, 4.0, 6.0]

[[planners]]
trajectory = "local_primitives"
gaze = "lookahead"

[[planners]]
trajectory = "local_primitives"
gaze = "fullrange"
'''


def _r2(x):
    """``x`` rounded to the two decimals the files keep, so that the checks see the numbers written."""
    return np.round(np.asarray(x, dtype=float), 2)


def _gap_3d(centre, reach: float, half_height: float, ball: float, pts: np.ndarray) -> np.ndarray:
    """A lower bound of the distance (m) from each point of ``pts`` [k, 3] to a static body that lies inside the
    vertical cylinder of radius ``reach`` and half height ``half_height`` about ``centre`` and inside the sphere
    of radius ``ball`` about it (its bounding sphere): the larger of the distances to the two."""
    d = pts - np.asarray(centre, float)
    across = np.maximum(np.hypot(d[:, 0], d[:, 1]) - reach, 0.0)
    up = np.maximum(np.abs(d[:, 2]) - half_height, 0.0)
    return np.maximum(np.hypot(across, up), np.linalg.norm(d, axis=1) - ball)


def _fits_3d(centre, reach: float, half_height: float, ball: float, taken: list, gap: float = 1.0) -> bool:
    """True when a static body bounded as in _gap_3d lies inside the arena, keeps CLEARANCE_M from every start/goal
    candidate and keeps ``gap`` from the bounding cylinders ``taken`` ((centre, reach, half height))."""
    c = np.asarray(centre, float)
    ext = np.array([reach, reach, half_height])
    if np.any(c - ext < 0.0) or np.any(c + ext > SIZE_3D):
        return False
    if _gap_3d(c, reach, half_height, ball, CANDIDATES_3D).min() < CLEARANCE_M:
        return False
    return all(np.hypot(*(c[:2] - o[:2])) >= reach + r + gap or abs(c[2] - o[2]) >= half_height + h + gap
               for o, r, h in taken)


def _place_3d(rng: np.random.Generator, reach: float, half_height: float, ball: float, taken: list,
              z: float | None = None, tries: int = 500):
    """A centre for a static body bounded as in _gap_3d (at height ``z``, or drawn), placed by _fits_3d and added to
    ``taken``; None when none is found."""
    for _ in range(tries):
        xy = _r2(rng.uniform(reach, SIZE_3D[:2] - reach))
        zc = z if z is not None else float(_r2(rng.uniform(half_height, SIZE_3D[2] - half_height)))
        c = np.array([*xy, zc])
        if _fits_3d(c, reach, half_height, ball, taken):
            taken.append((c, reach, half_height))
            return c
    return None


def _direction_3d(rng: np.random.Generator, max_elevation_deg: float) -> np.ndarray:
    """A unit vector of uniform heading and elevation uniform in +-max_elevation_deg."""
    a = rng.uniform(0.0, 2.0 * math.pi)
    e = math.radians(rng.uniform(-max_elevation_deg, max_elevation_deg))
    return np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])


def _count(rng: np.random.Generator, ranges, level: int) -> int:
    lo, hi = ranges[level]
    return int(rng.integers(lo, hi + 1))


def hangar(rng: np.random.Generator, level: int) -> str:
    """Rack columns (2/3/4 by level) of two rows each, box racks on the floor with up to 1/2/2 more stacked on top;
    shuttles (box.urdf) on waypoint loops up one aisle and down the next, changing height on the cross legs (3-4 /
    7-10 / 16-20), and carts crossing between the rows at constant velocity, slightly climbing or sinking (1-2 /
    2-4 / 5-7); movers 1 / 1.15 / 1.3 times the base size, speeds SPEEDS_3D[level]."""
    xs = np.linspace(12.0, 38.0, (2, 3, 4)[level])
    stack_p = (0.5, 0.6, 0.8)[level]
    out = []
    for i, x in enumerate(xs):
        for j in range(2):
            length = float(_r2(rng.uniform(8.0, 12.0)))
            y = 8.0 + length / 2.0 if j == 0 else 42.0 - length / 2.0
            z0 = 0.0
            for t in range(1 + (1, 2, 2)[level]):
                if t and rng.random() >= stack_p:
                    break
                h = float(_r2(rng.uniform(3.0, 5.0)))
                size = np.array([2.0, length, h])
                c = _r2([x, y, z0 + h / 2.0])
                if not _fits_3d(c, 0.5 * math.hypot(2.0, length), h / 2.0, 0.5 * float(np.linalg.norm(size)), []):
                    break
                out.append(_body(f"rack_{i}_{j}_{t}", "box.urdf", size, position=c))
                z0 += h
    aisles = np.concatenate([[7.0], (xs[:-1] + xs[1:]) / 2.0, [43.0]])
    lo, hi = SPEEDS_3D[level]
    grow = (1.0, 1.15, 1.3)[level]
    for k in range(_count(rng, ((3, 4), (7, 10), (16, 20)), level)):
        a = int(rng.integers(0, aisles.shape[0] - 1))
        x0, x1 = aisles[a], aisles[a + 1]
        y0, y1 = rng.uniform(4.5, 6.0), rng.uniform(44.0, 45.5)
        za, zb = rng.uniform(2.0, 18.0, size=2)
        loop = [[x0, y0, za], [x0, y1, za], [x1, y1, zb], [x1, y0, zb]]
        if rng.random() < 0.5:
            loop = loop[::-1]
        size = grow * np.array([rng.uniform(0.8, 1.4), rng.uniform(1.2, 2.2), rng.uniform(0.8, 1.4)])
        out.append(_body(f"shuttle_{k}", "box.urdf", size, motion="waypoints", waypoints=np.array(loop),
                         speed=float(rng.uniform(lo, hi))))
    for k in range(_count(rng, ((1, 2), (2, 4), (5, 7)), level)):
        speed = float(rng.uniform(lo, hi))
        e = math.radians(rng.uniform(-15.0, 15.0))
        sign = 1.0 if rng.random() < 0.5 else -1.0
        pos = [rng.uniform(8.0, 42.0), rng.uniform(21.0, 29.0), rng.uniform(2.0, 18.0)]
        out.append(_body(f"cart_cross_{k}", "box.urdf", grow * np.array([1.6, 1.0, 1.2]), position=pos,
                         motion="constant_velocity", velocity=[sign * speed * math.cos(e), 0.0, speed * math.sin(e)]))
    return "".join(out)


def atrium(rng: np.random.Generator, level: int) -> str:
    """Floor-to-ceiling pillars (3-4 / 5-6 / 7-9 by level; radius 0.5-1.0 / 0.6-1.3 / 0.8-1.6 m) and balls (8-10 /
    16-20 / 30-36; radius 0.4-1.0 / 0.5-1.4 / 0.6-1.8 m) at constant velocity in any heading, up to 40 deg up or
    down, speeds SPEEDS_3D[level]."""
    out, taken = [], []
    p_lo, p_hi = ((0.5, 1.0), (0.6, 1.3), (0.8, 1.6))[level]
    h = float(SIZE_3D[2])
    for k in range(_count(rng, ((3, 4), (5, 6), (7, 9)), level)):
        r = float(_r2(rng.uniform(p_lo, p_hi)))
        c = _place_3d(rng, r, h / 2.0, math.hypot(r, h / 2.0), taken, z=h / 2.0)
        if c is not None:
            out.append(_body(f"pillar_{k}", "pillar.urdf", [r, r, h], position=c))
    b_lo, b_hi = ((0.4, 1.0), (0.5, 1.4), (0.6, 1.8))[level]
    lo, hi = SPEEDS_3D[level]
    for k in range(_count(rng, ((8, 10), (16, 20), (30, 36)), level)):
        r = float(_r2(rng.uniform(b_lo, b_hi)))
        pos = rng.uniform(r, SIZE_3D - r)
        out.append(_body(f"ball_{k}", "sphere.urdf", r, position=pos, motion="constant_velocity",
                         velocity=float(rng.uniform(lo, hi)) * _direction_3d(rng, 40.0)))
    return "".join(out)


def orbits_3d(rng: np.random.Generator, level: int) -> str:
    """Static mesh bodies (2-3 / 3-5 / 5-7 by level; scale 1-2.5) anywhere in the volume, and movers (5-6 / 10-12 /
    22-26): mesh bodies and balls circling centres at any height (pbdyn.world.motions:circle, horizontal circles of
    radius 2-9 m, either way round) and every fourth a ball bobbing up and down (motions:bob, amplitude 2-7 m);
    speeds (the circle's, the bob's peak) SPEEDS_3D[level]."""
    out, taken = [], []
    for k in range(_count(rng, ((2, 3), (3, 5), (5, 7)), level)):
        s = float(_r2(rng.uniform(1.0, 2.5)))
        c = _place_3d(rng, s, s, s, taken)
        if c is not None:
            out.append(_body(f"gem_static_{k}", "../urdf/gem.urdf", s, position=c))
    lo, hi = SPEEDS_3D[level]
    gem = ((0.8, 1.5), (0.8, 1.8), (1.0, 2.2))[level]
    ball = ((0.5, 1.2), (0.5, 1.5), (0.7, 1.8))[level]
    for k in range(_count(rng, ((5, 6), (10, 12), (22, 26)), level)):
        is_gem = k % 2 == 0
        s = float(rng.uniform(*(gem if is_gem else ball)))
        speed = float(rng.uniform(lo, hi))
        if k % 4 == 3:
            amp = float(rng.uniform(2.0, 7.0))
            xy = rng.uniform(s + 0.5, SIZE_3D[:2] - s - 0.5)
            zc = float(rng.uniform(s + 0.5 + amp, SIZE_3D[2] - s - 0.5 - amp))
            params = {"center": [*xy, zc], "amplitude": amp, "period": 2.0 * math.pi * amp / speed}
            out.append(_body(f"ball_bob_{k}", "sphere.urdf", s, motion="pbdyn.world.motions:bob", params=params))
            continue
        radius = float(rng.uniform(2.0, 9.0))
        xy = rng.uniform(radius + s + 0.5, SIZE_3D[:2] - radius - s - 0.5)
        zc = float(rng.uniform(s + 0.5, SIZE_3D[2] - s - 0.5))
        turn = 2.0 * math.pi * radius / speed * (1.0 if rng.random() < 0.5 else -1.0)
        params = {"center": [*xy, zc], "radius": radius, "period": turn, "phase_deg": float(rng.uniform(0.0, 360.0))}
        name, urdf = (f"gem_orbit_{k}", "../urdf/gem.urdf") if is_gem else (f"ball_orbit_{k}", "sphere.urdf")
        out.append(_body(name, urdf, s, motion="pbdyn.world.motions:circle", params=params))
    return "".join(out)


BUILDERS_3D = {"hangar": hangar, "atrium": atrium, "orbits": orbits_3d}
OUT = {2: ROOT / "scenarios" / "worlds" / "imported_2d", 3: ROOT / "scenarios" / "worlds" / "imported_3d"}


def worlds(dims: int = 2) -> dict[str, str]:
    """File name -> text of every world of the 2D or the 3D set."""
    out = {}
    if dims == 3:
        for f, family in enumerate(FAMILIES_3D):
            for i in range(PER_FAMILY):
                seed = SEED_3D + 10 * f + i
                name = f"{family}_{i}"
                text = HEADER_3D.format(family=family, seed=seed, name=name)
                out[f"{name}.toml"] = text + BUILDERS_3D[family](np.random.default_rng(seed), i)
        return out
    for f, family in enumerate(FAMILIES):
        for i in range(PER_FAMILY):
            seed = 1000 + 10 * f + i
            name = f"{family}_{i}"
            text = HEADER.format(family=family, seed=seed, name=name)
            out[f"{name}.toml"] = text + BUILDERS[family](np.random.default_rng(seed))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--dims", type=int, choices=(2, 3), help="only the 2D or the 3D set (default: both)")
    ap.add_argument("--out", help="the set's folder (default scenarios/worlds/imported_<dims>d; needs --dims)")
    ap.add_argument("--check", action="store_true", help="verify the files instead of writing them")
    args = ap.parse_args(argv)
    if args.out is not None and args.dims is None:
        ap.error("--out needs --dims (the 2D and the 3D set have folders of their own)")
    status = 0
    for dims in ((args.dims,) if args.dims else (2, 3)):
        out = Path(args.out) if args.out is not None else OUT[dims]
        texts = worlds(dims)
        if args.check:
            bad = [n for n, t in texts.items() if not (out / n).is_file() or (out / n).read_text() != t]
            if bad:
                print(f"make_worlds: {len(bad)} {dims}D world file(s) in {out} differ from what this tool writes: "
                      f"{', '.join(bad)}", file=sys.stderr)
                status = 1
            else:
                print(f"make_worlds: {len(texts)} {dims}D world files as written")
            continue
        out.mkdir(parents=True, exist_ok=True)
        for n, t in texts.items():
            (out / n).write_text(t)
        print(f"make_worlds: wrote {len(texts)} {dims}D worlds to {out}")
    return status


if __name__ == "__main__":
    raise SystemExit(main())
