"""The scenario parser: a TOML file or a dict validated into the model (pbdyn.config.model), with the error messages
(docs/scenarios.md "Scenario reference").

Unknown keys and invalid values raise ConfigError naming the field and the value; every default comes from the
model's dataclasses (``_defaults``), never a literal here (tests/test_config_defaults.py).
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import replace
from pathlib import Path
from typing import Any, Mapping

from pbdyn import limits, resources
from pbdyn.config.model import (BODY_MOTIONS, BUILTIN_STRUCTURES, COLLISION_CHECKS, PROFILE_DEFAULTS, PROFILES,
                                START_RULES, BodyConfig, DroneConfig, MapEntry, ObstacleConfig, PlannerEntry, Range,
                                Scenario, SensorConfig, StaticObstacleConfig, StructureConfig, TaskConfig,
                                TrackingConfig, WorldConfig, _defaults, canonical_json, default_candidates, map_seed,
                                rollout_span_s)
from pbdyn.errors import ConfigError, check_finite_params
from pbdyn.motion.registry import MODELS
from pbdyn.urdf import check_urdf


def _name(where: str, key: str) -> str:
    return f"{where}.{key}" if where else key


def _is_number(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _number(table: Mapping, key: str, where: str, default: float | None, *, lo: float | None = None,
            lo_open: bool = False, hi: float | None = None) -> float:
    if key not in table:
        return default if default is None else float(default)
    return _check_number(table[key], _name(where, key), lo=lo, lo_open=lo_open, hi=hi)


def _check_number(value: Any, name: str, *, lo: float | None = None, lo_open: bool = False,
                  hi: float | None = None) -> float:
    if not _is_number(value):
        raise ConfigError(name, "must be a number", value)
    v = float(value)
    if not math.isfinite(v):
        raise ConfigError(name, "must be finite", value)
    if abs(v) > limits.MAX_MAGNITUDE:
        raise ConfigError(name, f"must be within +-{limits.MAX_MAGNITUDE:g} (pbdyn's limit for any scenario number)", value)
    if lo is not None and (v < lo or (lo_open and v == lo)):
        raise ConfigError(name, f"must be {'>' if lo_open else '>='} {lo:g}", value)
    if hi is not None and v > hi:
        raise ConfigError(name, f"must be <= {hi:g}", value)
    return v


def _integer(table: Mapping, key: str, where: str, default: int | None, *, lo: int | None = None) -> int | None:
    if key not in table:
        return default if default is None else int(default)
    v = table[key]
    if not isinstance(v, int) or isinstance(v, bool):
        raise ConfigError(_name(where, key), "must be an integer", v)
    if lo is not None and v < lo:
        raise ConfigError(_name(where, key), f"must be >= {lo}", v)
    return int(v)


def _string(table: Mapping, key: str, where: str, default: str, choices: tuple[str, ...] | None = None) -> str:
    if key not in table:
        return default
    v = table[key]
    if not isinstance(v, str):
        raise ConfigError(_name(where, key), "must be a string", v)
    if choices is not None and v not in choices:
        raise ConfigError(_name(where, key), f"must be one of {', '.join(choices)}", v)
    return v


def _table(doc: Mapping, key: str, where: str = "") -> Mapping:
    name = _name(where, key) if where else key
    v = doc.get(key, {})
    if not isinstance(v, Mapping):
        raise ConfigError(name, "must be a table", v)
    return v


def _no_unknown(table: Mapping, allowed: tuple[str, ...], where: str) -> None:
    for k in table:
        if k not in allowed:
            name = f"{where}.{k}" if where else k
            raise ConfigError(name, f"unknown key (allowed: {', '.join(allowed)})", table[k], show_value=False)


def _array_of_tables(doc: Mapping, key: str, what: str) -> list:
    """doc[key] ([] when absent): an array of at most limits.MAX_OBSTACLES ``what``; ConfigError naming ``key``
    otherwise."""
    items = doc.get(key, [])
    if not isinstance(items, list):
        raise ConfigError(key, f"must be an array of tables ([[{key}]])", items)
    limits.check_limit(key, what, len(items), limits.MAX_OBSTACLES, len(items))
    return items


def _tables(items: list, key: str):
    """(i, "key[i]", item) for each item of the array of tables ``key``; ConfigError unless the item is a table."""
    for i, t in enumerate(items):
        where = f"{key}[{i}]"
        if not isinstance(t, Mapping):
            raise ConfigError(where, "must be a table", t)
        yield i, where, t


def _vector(value: Any, name: str, dims: int) -> tuple[float, ...]:
    if not isinstance(value, (list, tuple)) or len(value) != dims:
        raise ConfigError(name, f"must be a list of {dims} numbers", value)
    return tuple(_check_number(x, f"{name}[{i}]") for i, x in enumerate(value))


def _parse_world(doc: Mapping) -> WorldConfig:
    t = _table(doc, "world")
    _no_unknown(t, ("dims", "size", "dt", "time_limit", "grid_resolution", "flight_height"), "world")
    d = _defaults(WorldConfig)
    dims = _integer(t, "dims", "world", d["dims"])
    if dims not in (2, 3):
        raise ConfigError("world.dims", "must be 2 or 3", dims)
    default_size = d["size"] if dims == 2 else WorldConfig.SIZE_3D
    size = _vector(t["size"], "world.size", dims) if "size" in t else default_size
    for i, s in enumerate(size):
        if s <= 0:
            raise ConfigError(f"world.size[{i}]", "must be > 0", s)
    dt = _number(t, "dt", "world", d["dt"], lo=0.0, lo_open=True, hi=1.0)
    time_limit = _number(t, "time_limit", "world", d["time_limit"], lo=0.0, lo_open=True)
    if time_limit < dt:
        raise ConfigError("world.time_limit", f"must be >= world.dt ({dt:g})", time_limit)
    res = _number(t, "grid_resolution", "world", d["grid_resolution"], lo=0.0, lo_open=True)
    if res > min(size) / 2:
        raise ConfigError("world.grid_resolution", "must be at most half the arena's smallest side", res)
    h = _number(t, "flight_height", "world", d["flight_height"], lo=0.0, lo_open=True)
    steps = (max(time_limit, limits.METRICS_HORIZON_S) + dt) / dt
    limits.check_limit("world.dt" if "dt" in t else "world.time_limit",
                       f"rollout steps ((max(world.time_limit, {limits.METRICS_HORIZON_S:g} s) + dt) / dt)", steps,
                       limits.MAX_STEPS, dt if "dt" in t else time_limit)
    cells = math.prod(float(math.ceil(s / res - 1e-9) + 2) for s in size)
    limits.check_limit("world.grid_resolution" if "grid_resolution" in t else "world.size",
                       "occupancy-grid cells (world.size / world.grid_resolution)", cells, limits.MAX_GRID_CELLS,
                       res if "grid_resolution" in t else list(size))
    return WorldConfig(dims, tuple(size), dt, time_limit, res, h)


def _grid_values(value: Any, name: str, *, integer: bool = False, allow_range: bool = True,
                 lo: float = 0.0, lo_open: bool = True) -> tuple:
    items = value if isinstance(value, list) else [value]
    if isinstance(value, list) and not value:
        raise ConfigError(name, "must not be an empty list", value)
    out = []
    for i, item in enumerate(items):
        iname = f"{name}[{i}]" if isinstance(value, list) else name
        if integer:
            if not isinstance(item, int) or isinstance(item, bool):
                raise ConfigError(iname, "must be an integer", item)
            if item < lo:
                raise ConfigError(iname, f"must be >= {lo:g}", item)
            out.append(int(item))
        elif isinstance(item, Mapping):
            if not allow_range:
                raise ConfigError(iname, "must be a number", dict(item))
            _no_unknown(item, ("min", "max"), iname)
            if "min" not in item or "max" not in item:
                raise ConfigError(iname, "a range needs both min and max", dict(item))
            a = _check_number(item["min"], f"{iname}.min", lo=lo, lo_open=lo_open)
            b = _check_number(item["max"], f"{iname}.max", lo=lo, lo_open=lo_open)
            if b < a:
                raise ConfigError(f"{iname}.max", f"must be >= min ({a:g})", b)
            out.append(Range(a, b))
        else:
            out.append(_check_number(item, iname, lo=lo, lo_open=lo_open))
    if len(set(map(canonical_json, out))) != len(out):
        raise ConfigError(name, "grid values must be distinct", value)
    return tuple(out)


def _parse_obstacles(doc: Mapping) -> ObstacleConfig:
    t = _table(doc, "obstacles")
    keys = ("count", "radius", "speed", "radius_jitter", "motion", "maps_per_setup", "root_seed", *_motion_tables(),
            "headings", "structure", "structures", "layout", "wall_turn", "maps")
    _no_unknown(t, keys, "obstacles")
    if "maps" in t:
        return _parse_map_list(t)
    return _parse_obstacles_grid(t)


def _parse_obstacles_grid(t: Mapping) -> ObstacleConfig:
    """obstacles whose maps are the grid's setups x maps_per_setup replicates."""
    d = _defaults(ObstacleConfig)
    count = _grid_values(t["count"], "obstacles.count", integer=True, lo=0) if "count" in t else d["count"]
    radius = _grid_values(t["radius"], "obstacles.radius") if "radius" in t else d["radius"]
    speed = (_grid_values(t["speed"], "obstacles.speed", lo=0.0, lo_open=False) if "speed" in t
             else d["speed"])
    jitter = _number(t, "radius_jitter", "obstacles", d["radius_jitter"], lo=0.0)
    for i, r in enumerate(radius):
        rmin = r.min if isinstance(r, Range) else r
        if rmin - jitter <= 0:
            raise ConfigError("obstacles.radius_jitter", f"must be < the smallest radius ({rmin:g})", jitter)
    motion = _string(t, "motion", "obstacles", d["motion"], tuple(MODELS))
    for i, n in enumerate(count):
        limits.check_limit(f"obstacles.count[{i}]" if isinstance(t.get("count"), list) else "obstacles.count",
                           "obstacles", n, limits.MAX_OBSTACLES, n)
    maps = _integer(t, "maps_per_setup", "obstacles", d["maps_per_setup"], lo=1)
    limits.check_limit("obstacles.maps_per_setup", "maps per setup", maps, limits.MAX_MAPS_PER_SETUP, maps)
    limits.check_limit("obstacles", "setups (the product of the lengths of count, radius and speed)",
                       len(count) * len(radius) * len(speed), limits.MAX_SETUPS,
                       {"count": len(count), "radius": len(radius), "speed": len(speed)})
    seed = _integer(t, "root_seed", "obstacles", d["root_seed"], lo=0)
    order = tuple(k for k in t if k in d["grid_order"])
    order += tuple(k for k in d["grid_order"] if k not in order)
    tables = _parse_motion_tables(t, motion)
    headings = _string(t, "headings", "obstacles", d["headings"], ObstacleConfig.HEADINGS)
    structure, structures = _parse_structures(t, motion)
    if structure:
        order = order if "structure" in order else order + ("structure",)
        limits.check_limit("obstacles", "setups (the product of the lengths of count, radius, speed and structure)",
                           len(count) * len(radius) * len(speed) * len(structure), limits.MAX_SETUPS,
                           {"count": len(count), "radius": len(radius), "speed": len(speed),
                            "structure": len(structure)})
    else:
        order = tuple(k for k in order if k != "structure")
    layout = _string(t, "layout", "obstacles", d["layout"], ObstacleConfig.LAYOUTS)
    wall_turn = _string(t, "wall_turn", "obstacles", d["wall_turn"], ObstacleConfig.WALL_TURNS)
    if wall_turn == "program" and motion != "cvm":
        raise ConfigError("obstacles.wall_turn", 'is only used with motion = "cvm"', wall_turn)
    if layout == "program":
        why = ('needs headings = "even" (the program\'s)' if headings != "even" else
               "needs exact speeds (the program gave every obstacle the setup speed)"
               if any(isinstance(v, Range) for v in speed) else
               "cannot be combined with structures" if structure else "")
        if why:
            raise ConfigError("obstacles.layout", f'"program" {why}', layout)
    return ObstacleConfig(count, radius, speed, jitter, motion, maps, seed, order, headings=headings,
                          structure=structure, structures=structures, layout=layout, wall_turn=wall_turn, **tables)


def _motion_tables() -> tuple[str, ...]:
    """The names of the motion models' own tables ([obstacles.<table>], pbdyn.motion.registry)."""
    return tuple(m.table for m in MODELS.values() if m.table is not None)


def _parse_motion_tables(t: Mapping, motion: str) -> dict[str, Any]:
    """Every motion model's own table [obstacles.<table>] parsed into its params_type (pbdyn.motion.registry): each
    key checked against the model's table_keys (type, lower bound), omitted keys at the dataclass defaults, then
    the model's check_params. A table of a model that is not ``motion`` is refused. Returns table name -> params
    (the ObstacleConfig fields of the same names)."""
    out = {}
    for model in MODELS.values():
        if model.table is None:
            continue
        where = f"obstacles.{model.table}"
        given = _table(t, model.table, "obstacles")
        if given and motion != model.name:
            raise ConfigError(where, f'is only used with motion = "{model.name}"', dict(given), show_value=False)
        _no_unknown(given, tuple(k.name for k in model.table_keys), where)
        d = _defaults(model.params_type)
        values = {k.name: _integer(given, k.name, where, d[k.name], lo=k.lo) if k.integer
                  else _number(given, k.name, where, d[k.name], lo=k.lo, lo_open=k.lo_open)
                  for k in model.table_keys}
        params = model.params_type(**values)
        model.check_params(params, given, where)
        out[model.table] = params
    return out


def _parse_map_list(t: Mapping) -> ObstacleConfig:
    """obstacles with an explicit map list ([[obstacles.maps]]): the grid fields (count, radius, speed, structure,
    maps_per_setup) are then not used and refused; each map names its own setup values and replicate."""
    for key in ("count", "radius", "speed", "structure", "maps_per_setup"):
        if key in t:
            raise ConfigError(f"obstacles.{key}", "is not used when obstacles.maps lists the maps (each map gives its "
                              "own values)", t[key])
    items = t["maps"]
    if not isinstance(items, list) or not items:
        raise ConfigError("obstacles.maps", "must be a non-empty array of tables ([[obstacles.maps]])", items,
                          show_value=not isinstance(items, list))
    limits.check_limit("obstacles.maps", "maps", len(items), limits.MAX_SETUPS * 10, len(items))
    base = {k: v for k, v in t.items() if k != "maps"}
    tables = _table(t, "structures", "obstacles")
    names: list[str] = []
    entries = []
    for _, where, m in _tables(items, "obstacles.maps"):
        _no_unknown(m, ("count", "radius", "speed", "structure", "replicate", "seed", "measured"), where)
        for key in ("count", "radius", "speed"):
            if key not in m:
                raise ConfigError(f"{where}.{key}", "is required", None, show_value=False)
        (count,) = _grid_values(m["count"], f"{where}.count", integer=True, lo=0)
        limits.check_limit(f"{where}.count", "obstacles", count, limits.MAX_OBSTACLES, count)
        (radius,) = _grid_values(m["radius"], f"{where}.radius")
        (speed,) = _grid_values(m["speed"], f"{where}.speed", lo=0.0, lo_open=False)
        structure = m.get("structure")
        if structure is not None:
            if not isinstance(structure, str) or (structure not in tables and structure not in BUILTIN_STRUCTURES):
                raise ConfigError(f"{where}.structure", f"unknown structure (built-in: "
                                  f"{', '.join(BUILTIN_STRUCTURES)}; or define [obstacles.structures.NAME])", structure)
            if structure not in names:
                names.append(structure)
        replicate = _integer(m, "replicate", where, _defaults(MapEntry)["replicate"], lo=0)
        seed = _integer(m, "seed", where, None, lo=0) if "seed" in m else None
        measured = m.get("measured", {})
        if not isinstance(measured, Mapping) or not all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in measured.values()):
            raise ConfigError(f"{where}.measured", "must be a table of finite numbers", measured)
        entries.append(MapEntry(count, radius, speed, structure, replicate, seed, dict(measured)))
    keys = [canonical_json({"setup": e.setup(), "replicate": e.replicate}) for e in entries]
    for i, k in enumerate(keys):
        if keys.index(k) != i:
            raise ConfigError(f"obstacles.maps[{i}]", f"is the same map as obstacles.maps[{keys.index(k)}] (same "
                              "setup values and replicate)", dict(items[i]), show_value=False)
    if names:
        base["structure"] = names
    else:
        base.pop("structures", None) if not tables else None
    grid = _parse_obstacles_grid(base)
    out = replace(grid, maps=tuple(entries), structure=(), count=(entries[0].count,), radius=(entries[0].radius,),
                  speed=(entries[0].speed,), maps_per_setup=1,
                  grid_order=tuple(k for k in grid.grid_order if k != "structure"))
    for i, e in enumerate(entries):
        key = canonical_json({"setup": e.setup(), "replicate": e.replicate})
        if e.seed is not None and map_seed(out.root_seed, key) != e.seed:
            raise ConfigError(f"obstacles.maps[{i}].seed", "is not the seed its setup values, replicate and "
                              "obstacles.root_seed give: the map would not be the one recorded (was root_seed or a "
                              "value edited?)", e.seed)
        jitter_min = e.radius.min if isinstance(e.radius, Range) else e.radius
        if jitter_min - out.radius_jitter <= 0:
            raise ConfigError("obstacles.radius_jitter", f"must be < every listed map's radius ({jitter_min:g})",
                              out.radius_jitter)
    return out


def _optional_choice(t: Mapping, key: str, where: str, default: str | None, choices: tuple[str, ...]) -> str | None:
    """t[key] when it is one of ``choices``, ``default`` (possibly None: "the scenario's") when absent."""
    if key not in t:
        return default
    v = t[key]
    if not isinstance(v, str) or v not in choices:
        raise ConfigError(_name(where, key), f"must be one of {', '.join(choices)}", v)
    return v


def _parse_structure(name: str, t: Mapping, where: str) -> StructureConfig:
    """One structure: the built-in named ``name`` (if any) with the table ``t`` applied over it."""
    d = {**_defaults(StructureConfig), **BUILTIN_STRUCTURES.get(name, {})}
    allowed = tuple(k for k in d if k != "name")
    _no_unknown(t, allowed, where)
    layout = _string(t, "layout", where, d["layout"], StructureConfig.LAYOUTS)
    headings = _optional_choice(t, "headings", where, d["headings"], StructureConfig.HEADINGS)
    motion = _optional_choice(t, "motion", where, d["motion"], tuple(MODELS))
    frac = _number(t, "static_fraction", where, d["static_fraction"], lo=0.0)
    if frac > 1.0:
        raise ConfigError(_name(where, "static_fraction"), "must be in [0, 1]", frac)
    walls = _integer(t, "walls", where, d["walls"], lo=0)
    limits.check_limit(_name(where, "walls"), "walls", walls, limits.MAX_OBSTACLES, walls)
    gaps = _integer(t, "gaps_per_wall", where, d["gaps_per_wall"], lo=1)
    limits.check_limit(_name(where, "gaps_per_wall"), "gaps per wall", gaps, limits.MAX_OBSTACLES, gaps)
    clusters = _integer(t, "clusters", where, d["clusters"], lo=1)
    limits.check_limit(_name(where, "clusters"), "clusters", clusters, limits.MAX_OBSTACLES, clusters)
    return StructureConfig(
        name=name, layout=layout, clusters=clusters,
        cluster_spread=_number(t, "cluster_spread", where, d["cluster_spread"], lo=0.0, lo_open=True),
        headings=headings,
        crossing_window_s=_number(t, "crossing_window_s", where, d["crossing_window_s"], lo=0.0, lo_open=True),
        static_fraction=frac,
        radius_spread=_number(t, "radius_spread", where, d["radius_spread"], lo=0.0),
        speed_spread=_number(t, "speed_spread", where, d["speed_spread"], lo=0.0),
        walls=walls, wall_gap=_number(t, "wall_gap", where, d["wall_gap"], lo=0.0, lo_open=True),
        wall_thickness=_number(t, "wall_thickness", where, d["wall_thickness"], lo=0.0, lo_open=True),
        gaps_per_wall=gaps, motion=motion)


def _parse_structures(t: Mapping, motion: str) -> tuple[tuple[str, ...], tuple[StructureConfig, ...]]:
    """(obstacles.structure grid values, the StructureConfigs they name), from obstacles.structure and the
    [obstacles.structures.NAME] tables (names not given a table must be built-in)."""
    tables = _table(t, "structures", "obstacles")
    for name in tables:
        if not isinstance(tables[name], Mapping):
            raise ConfigError(f"obstacles.structures.{name}", "must be a table", tables[name])
    if "structure" not in t:
        if tables:
            raise ConfigError("obstacles.structures", "is only used with obstacles.structure", dict(tables),
                              show_value=False)
        return (), ()
    raw = t["structure"]
    names = [raw] if isinstance(raw, str) else raw
    if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
        raise ConfigError("obstacles.structure", "must be a name or a non-empty array of names", raw)
    if len(set(names)) != len(names):
        raise ConfigError("obstacles.structure", "grid values must be distinct", raw)
    out = []
    for i, name in enumerate(names):
        where = "obstacles.structure" if isinstance(raw, str) else f"obstacles.structure[{i}]"
        if name not in tables and name not in BUILTIN_STRUCTURES:
            raise ConfigError(where, f"unknown structure (built-in: {', '.join(BUILTIN_STRUCTURES)}; or define "
                              f"[obstacles.structures.{name}])", name)
        out.append(_parse_structure(name, tables.get(name, {}), f"obstacles.structures.{name}"))
    unused = sorted(set(tables) - set(names))
    if unused:
        raise ConfigError(f"obstacles.structures.{unused[0]}", "is defined but not listed in obstacles.structure",
                          unused[0])
    return tuple(names), tuple(out)


def _parse_static(doc: Mapping, world: WorldConfig) -> tuple[StaticObstacleConfig, ...]:
    items = _array_of_tables(doc, "static_obstacles", "static obstacles")
    sd = _defaults(StaticObstacleConfig)
    out = []
    for _, where, t in _tables(items, "static_obstacles"):
        _no_unknown(t, ("kind", "center", "radius", "size", "yaw_deg"), where)
        kind = _string(t, "kind", where, StaticObstacleConfig.DEFAULT_KIND, StaticObstacleConfig.KINDS)
        if "center" not in t:
            raise ConfigError(f"{where}.center", "is required", None, show_value=False)
        center = _vector(t["center"], f"{where}.center", world.dims)
        for k, c in enumerate(center):
            if not 0 <= c <= world.size[k]:
                raise ConfigError(f"{where}.center[{k}]", f"must lie in the arena [0, {world.size[k]:g}]", c)
        yaw = _number(t, "yaw_deg", where, sd["yaw_deg"])
        if kind == "pillar":
            if "size" in t:
                raise ConfigError(f"{where}.size", "is for boxes; a pillar has a radius", t["size"])
            if "radius" not in t:
                raise ConfigError(f"{where}.radius", "is required for a pillar", None, show_value=False)
            radius = _check_number(t["radius"], f"{where}.radius", lo=0.0, lo_open=True)
            out.append(StaticObstacleConfig(kind, center, radius, sd["size"], yaw))
        else:
            if "radius" in t:
                raise ConfigError(f"{where}.radius", "is for pillars; a box has a size", t["radius"])
            if "size" not in t:
                raise ConfigError(f"{where}.size", "is required for a box", None, show_value=False)
            size = _vector(t["size"], f"{where}.size", world.dims)
            for k, s in enumerate(size):
                if s <= 0:
                    raise ConfigError(f"{where}.size[{k}]", "must be > 0", s)
            out.append(StaticObstacleConfig(kind, center, sd["radius"], size, yaw))
    return tuple(out)


def _parse_motion(t: Mapping, where: str, world: WorldConfig) -> tuple[str, tuple, tuple, tuple, dict]:
    bd = _defaults(BodyConfig)
    motion = t.get("motion", bd["motion"])
    if not isinstance(motion, str) or not motion:
        raise ConfigError(f"{where}.motion", f"must be one of {', '.join(BODY_MOTIONS)} or 'package.module:function'",
                          motion)
    if motion not in BODY_MOTIONS:
        mod, _, fn = motion.partition(":")
        if not mod or not fn:
            raise ConfigError(f"{where}.motion",
                              f"must be one of {', '.join(BODY_MOTIONS)} or 'package.module:function'", motion)
    velocity, waypoints, speed = bd["velocity"], bd["waypoints"], bd["speed"]
    allowed = {"constant_velocity": ("velocity",), "waypoints": ("waypoints", "speed")}.get(motion, ())
    if motion not in BODY_MOTIONS:
        allowed = ("params",)
    for key in ("velocity", "waypoints", "speed", "params"):
        if key in t and key not in allowed:
            raise ConfigError(f"{where}.{key}", f'is not used with motion = "{motion}"', t[key])
    if motion == "constant_velocity":
        if "velocity" not in t:
            raise ConfigError(f"{where}.velocity", "is required with motion = \"constant_velocity\"", None,
                              show_value=False)
        velocity = _vector(t["velocity"], f"{where}.velocity", world.dims)
    elif motion == "waypoints":
        raw = t.get("waypoints")
        if not isinstance(raw, list) or len(raw) < 2:
            raise ConfigError(f"{where}.waypoints", "must be a list of at least 2 points", raw)
        waypoints = tuple(_vector(w, f"{where}.waypoints[{i}]", world.dims) for i, w in enumerate(raw))
        for i, w in enumerate(waypoints):
            if w == waypoints[(i + 1) % len(waypoints)]:
                raise ConfigError(f"{where}.waypoints[{i}]", "repeats the next waypoint (a leg of length 0)", list(w))
        if "speed" not in t:
            raise ConfigError(f"{where}.speed", "is required with motion = \"waypoints\"", None, show_value=False)
        raw_speed = t["speed"]
        items = raw_speed if isinstance(raw_speed, list) else [raw_speed]
        speed = tuple(_check_number(v, f"{where}.speed", lo=0.0, lo_open=True) for v in items)
        if len(speed) not in (1, len(waypoints)):
            raise ConfigError(f"{where}.speed", f"must be one speed or one per leg ({len(waypoints)})", raw_speed)
    params = dict(_table(t, "params", where))
    return motion, velocity, waypoints, speed, params


def _parse_bodies(doc: Mapping, world: WorldConfig) -> tuple[BodyConfig, ...]:
    items = _array_of_tables(doc, "bodies", "bodies")
    bd = _defaults(BodyConfig)
    out = []
    names = set()
    for i, where, t in _tables(items, "bodies"):
        _no_unknown(t, ("name", "urdf", "scale", "position", "rpy_deg", "motion", "velocity", "waypoints", "speed",
                        "params"), where)
        name = _string(t, "name", where, BodyConfig.DEFAULT_NAME.format(index=i))
        if name in names:
            raise ConfigError(f"{where}.name", "is used by another body", name)
        names.add(name)
        if "urdf" not in t:
            raise ConfigError(f"{where}.urdf", "is required", None, show_value=False)
        urdf = _string(t, "urdf", where, None)
        if not urdf:
            raise ConfigError(f"{where}.urdf", "must be a file path", t["urdf"])
        scale = bd["scale"]
        if "scale" in t:
            raw_scale = t["scale"]
            scale = (_vector(raw_scale, f"{where}.scale", 3) if isinstance(raw_scale, list)
                     else (_check_number(raw_scale, f"{where}.scale"),) * 3)
            for v in scale:
                if v <= 0:
                    raise ConfigError(f"{where}.scale", "must be > 0", raw_scale)
        motion, velocity, waypoints, speed, params = _parse_motion(t, where, world)
        if "position" in t:
            if motion == "waypoints":
                raise ConfigError(f"{where}.position", "is not used with waypoints (the base starts at waypoints[0])",
                                  t["position"])
            raw = t["position"]
            n = len(raw) if isinstance(raw, list) else 0
            if world.dims == 2 and n == 2:
                position = _vector(raw, f"{where}.position", 2) + (world.flight_height,)
            else:
                position = _vector(raw, f"{where}.position", 3)
        elif motion == "waypoints":
            w0 = waypoints[0]
            position = w0 + ((world.flight_height,) if world.dims == 2 else ())
        elif motion in BODY_MOTIONS:
            raise ConfigError(f"{where}.position", "is required", None, show_value=False)
        else:
            position = bd["position"]   # a motion function gives every pose
        rpy = _vector(t["rpy_deg"], f"{where}.rpy_deg", 3) if "rpy_deg" in t else bd["rpy_deg"]
        for key, points in (("position", [position] if "position" in t else []), ("waypoints", waypoints)):
            for pt in points:
                if not all(0.0 <= pt[a] <= world.size[a] for a in range(world.dims)):
                    raise ConfigError(f"{where}.{key}", "must lie inside the arena "
                                      f"[0, {', '.join(f'{s:g}' for s in world.size)}]", list(pt))
        out.append(BodyConfig(name, urdf, tuple(scale), tuple(position), tuple(rpy), motion, velocity, waypoints,
                              speed, params))
    return tuple(out)


def _parse_drone(doc: Mapping) -> DroneConfig:
    t = _table(doc, "drone")
    _no_unknown(t, ("urdf", "radius", "a_max", "v_max", "yaw_rate_limit"), "drone")
    d = _defaults(DroneConfig)
    urdf = _string(t, "urdf", "drone", d["urdf"])
    radius = _number(t, "radius", "drone", d["radius"], lo=0.0, lo_open=True)
    a_max = _number(t, "a_max", "drone", d["a_max"], lo=0.0, lo_open=True)
    v_max = _grid_values(t["v_max"], "drone.v_max", allow_range=False) if "v_max" in t else d["v_max"]
    yaw = _number(t, "yaw_rate_limit", "drone", d["yaw_rate_limit"], lo=0.0, lo_open=True)
    return DroneConfig(urdf, radius, a_max, tuple(float(v) for v in v_max), yaw)


def check_v_max(value: Any, field: str = "v_max") -> float:
    """A MAV speed limit (m/s) under the limits of drone.v_max (a finite number > 0, at most limits.MAX_MAGNITUDE);
    ConfigError naming ``field`` otherwise."""
    return _check_number(value, field, lo=0.0, lo_open=True)


def stopping_distance(v: float, a_max: float, dt: float) -> float:
    """Distance (m) a MAV flying at ``v`` m/s covers before it is at rest: one step of dt at v (what it senses at t_k
    changes its motion from t_k+1 on) plus braking at a_max, v^2 / (2 a_max)."""
    return v * dt + v * v / (2.0 * a_max)


def warn_stopping(scenario: "Scenario", speeds, field: str) -> None:
    """A PbdynWarning naming ``field`` if a MAV at one of ``speeds`` (m/s) cannot stop within the sensor range
    (stopping_distance > sensor.range): it may not stop for an obstacle it has just seen, and trials tend to end
    in deadlock or collision."""
    a_max, dt, rng = scenario.drone.a_max, scenario.world.dt, scenario.sensor.range
    fast = sorted(v for v in speeds if stopping_distance(v, a_max, dt) > rng)
    if not fast:
        return
    import warnings

    from pbdyn.errors import PbdynWarning

    safe = a_max * (math.sqrt(dt * dt + 2.0 * rng / a_max) - dt)
    need = stopping_distance(fast[-1], a_max, dt)
    warnings.warn(PbdynWarning(field, f"at {', '.join(f'{v:g}' for v in fast)} m/s the MAV needs "
                               f"{'up to ' if len(fast) > 1 else ''}{need:.3g} m to stop (v dt + v^2 / (2 a_max), "
                               f"a_max = {a_max:g} m/s^2), more than the sensor range of {rng:g} m: it cannot stop "
                               f"for an obstacle it has just seen (at most {safe:.3g} m/s can)"), stacklevel=3)


def _parse_sensor(doc: Mapping, world: WorldConfig) -> SensorConfig:
    t = _table(doc, "sensor")
    _no_unknown(t, ("fov_deg", "vfov_deg", "range", "resolution_deg", "noise_std", "model", "rays", "march_step",
                    "obstacles_at", "march_rule"), "sensor")
    d = _defaults(SensorConfig)
    fov = _number(t, "fov_deg", "sensor", d["fov_deg"], lo=0.0, lo_open=True, hi=360.0)
    rng = _number(t, "range", "sensor", d["range"], lo=0.0, lo_open=True)
    res = _number(t, "resolution_deg", "sensor", d["resolution_deg"] if world.dims == 2
                  else SensorConfig.RESOLUTION_3D_DEG, lo=0.0, lo_open=True)
    if res > fov:
        raise ConfigError("sensor.resolution_deg", f"must be <= sensor.fov_deg ({fov:g})", res)
    noise = _number(t, "noise_std", "sensor", d["noise_std"], lo=0.0)
    vfov = d["vfov_deg"]
    if world.dims == 3:
        vfov = _number(t, "vfov_deg", "sensor", SensorConfig.VFOV_3D_DEG, lo=0.0, lo_open=True, hi=180.0)
        if res > vfov:
            raise ConfigError("sensor.resolution_deg", f"must be <= sensor.vfov_deg ({vfov:g})", res)
    elif "vfov_deg" in t:
        raise ConfigError("sensor.vfov_deg", "is only used in 3D worlds (world.dims = 3)", t["vfov_deg"])
    rays = (360.0 / res + 1) * ((vfov / res + 1) if vfov is not None else 1)
    limits.check_limit("sensor.resolution_deg", "rays per scan (at 360 deg: a gaze planner may widen the fov)", rays,
                       limits.MAX_SENSOR_RAYS, res)
    model = _string(t, "model", "sensor", d["model"], SensorConfig.MODELS)
    n_rays, step, march_rule = d["rays"], d["march_step"], d["march_rule"]
    if model == "marching":
        march_rule = _string(t, "march_rule", "sensor", d["march_rule"], SensorConfig.MARCH_RULES)
        n_rays = _integer(t, "rays", "sensor", d["rays"], lo=1)
        step = _number(t, "march_step", "sensor", d["march_step"], lo=0.0, lo_open=True, hi=rng)
        if n_rays is not None:
            rays = n_rays * ((vfov / res + 1) if vfov is not None else 1)
            limits.check_limit("sensor.rays", "rays per scan", rays, limits.MAX_SENSOR_RAYS, n_rays)
        limits.check_limit("sensor.march_step", "march points per scan", rays * math.ceil(rng / step),
                           limits.MAX_SENSOR_MARCH_POINTS, step)
    else:
        for key in ("rays", "march_step", "march_rule"):
            if key in t:
                raise ConfigError(f"sensor.{key}", 'is only used with sensor.model = "marching"', t[key])
    obstacles_at = _string(t, "obstacles_at", "sensor", d["obstacles_at"], SensorConfig.OBSTACLES_AT)
    return SensorConfig(fov, rng, res, noise, vfov, model, n_rays, step, obstacles_at, march_rule)


def _check_resolution(sensor: SensorConfig, obstacles: ObstacleConfig,
                      static: tuple[StaticObstacleConfig, ...]) -> None:
    """Reject a ray spacing too coarse to hit the smallest obstacle at full range: adjacent rays at range R are
    res apart in angle, and an obstacle of radius r there spans 2 asin(r / R)."""
    radii = []
    for r in obstacles.radius:
        radii.append((r.min if isinstance(r, Range) else r) - obstacles.radius_jitter)
    radii += [s.radius for s in static if s.kind == "pillar"]
    if not radii or max(obstacles.count) == 0 and not static:
        return
    r_min = min(radii)
    span = math.degrees(2.0 * math.asin(min(r_min / sensor.range, 1.0)))
    if sensor.resolution_deg >= span:
        raise ConfigError("sensor.resolution_deg",
                          f"rays {sensor.resolution_deg:g} deg apart can miss an obstacle of radius {r_min:g} m at "
                          f"the {sensor.range:g} m range (it spans {span:.2f} deg)", sensor.resolution_deg)


def _parse_tracking(doc: Mapping) -> TrackingConfig:
    t = _table(doc, "tracking")
    _no_unknown(t, ("q", "r", "p0_pos", "p0_vel", "drop_pos_var", "drop_rule", "track_radius"), "tracking")
    d = _defaults(TrackingConfig)
    out = TrackingConfig(
        q=_number(t, "q", "tracking", d["q"], lo=0.0),
        r=_number(t, "r", "tracking", d["r"], lo=0.0),
        p0_pos=_number(t, "p0_pos", "tracking", d["p0_pos"], lo=TrackingConfig.MIN_VARIANCE),
        p0_vel=_number(t, "p0_vel", "tracking", d["p0_vel"], lo=TrackingConfig.MIN_VARIANCE),
        drop_pos_var=_number(t, "drop_pos_var", "tracking", d["drop_pos_var"], lo=0.0, lo_open=True),
        drop_rule=_string(t, "drop_rule", "tracking", d["drop_rule"], TrackingConfig.DROP_RULES),
        track_radius=_string(t, "track_radius", "tracking", d["track_radius"], TrackingConfig.TRACK_RADII),
    )
    tiny = TrackingConfig.MIN_VARIANCE
    for key in ("q", "r"):
        v = getattr(out, key)
        if 0.0 < v < tiny:
            raise ConfigError(f"tracking.{key}", f"must be 0 or >= {tiny:g} (smaller variances underflow)", v)
    if out.q == 0.0 and out.r == 0.0:
        raise ConfigError("tracking.q", "must be > 0 when tracking.r = 0 (with no process and no measurement noise "
                          "the Kalman innovation covariance becomes singular)", t.get("q", out.q))
    return out


def _parse_task(doc: Mapping, world: WorldConfig, drone: DroneConfig) -> TaskConfig:
    t = _table(doc, "task")
    _no_unknown(t, ("candidates", "goal_radius", "spawn_clearance", "deadlock_steps", "start_rule", "start_clearance",
                    "start_window_s", "start_wait_max_s", "start_yaw_deg", "pairs_flown"), "task")
    d = _defaults(TaskConfig)
    if "candidates" in t:
        raw = t["candidates"]
        if not isinstance(raw, list) or len(raw) < 2:
            raise ConfigError("task.candidates", "must be a list of at least 2 points", raw)
        cands = tuple(_vector(c, f"task.candidates[{i}]", world.dims) for i, c in enumerate(raw))
    else:
        cands = d["candidates"] or default_candidates(world)
    for i, c in enumerate(cands):
        for k, x in enumerate(c):
            if not drone.radius <= x <= world.size[k] - drone.radius:
                raise ConfigError(f"task.candidates[{i}]",
                                  f"must lie inside the arena with the MAV's radius ({drone.radius:g} m) to spare",
                                  list(c))
    if len(set(cands)) != len(cands):
        raise ConfigError("task.candidates", "must be distinct points", [list(c) for c in cands])
    goal_radius = _number(t, "goal_radius", "task", d["goal_radius"], lo=0.0, lo_open=True)
    clearance = _number(t, "spawn_clearance", "task", d["spawn_clearance"], lo=0.0)
    deadlock = _integer(t, "deadlock_steps", "task", d["deadlock_steps"], lo=1)
    rule = _string(t, "start_rule", "task", d["start_rule"], START_RULES)
    start_clearance = _number(t, "start_clearance", "task", d["start_clearance"], lo=0.0,
                              hi=max(world.size))
    window = _number(t, "start_window_s", "task", d["start_window_s"], lo=0.0, hi=limits.MAX_START_WAIT_S)
    wait = _number(t, "start_wait_max_s", "task", d["start_wait_max_s"], lo=0.0, hi=limits.MAX_START_WAIT_S)
    yaw = None if t.get("start_yaw_deg") == "goal" else _number(t, "start_yaw_deg", "task", d["start_yaw_deg"],
                                                                 lo=-360.0, hi=360.0)
    flown = _pairs_flown(t, len(cands))
    return TaskConfig(cands, goal_radius, clearance, deadlock, rule, start_clearance, window, wait, yaw, flown)


def _pairs_flown(t: Mapping, n: int) -> tuple[tuple[int, int], ...]:
    """task.pairs_flown: distinct [start, goal] index pairs of the n candidates, start != goal (() if absent)."""
    if "pairs_flown" not in t:
        return ()
    raw = t["pairs_flown"]
    if not isinstance(raw, list) or not raw:
        raise ConfigError("task.pairs_flown", "must be a non-empty list of [start, goal] candidate index pairs", raw)
    out = []
    for k, p in enumerate(raw):
        ok = isinstance(p, list) and len(p) == 2 and all(isinstance(x, int) and not isinstance(x, bool) for x in p)
        if not ok or not all(0 <= x < n for x in p) or p[0] == p[1]:
            raise ConfigError(f"task.pairs_flown[{k}]", f"must be [start, goal]: two different candidate indices in "
                              f"[0, {n - 1}]", p)
        out.append((p[0], p[1]))
    if len(set(out)) != len(out):
        raise ConfigError("task.pairs_flown", "must list each pair once", raw)
    return tuple(out)


def _parse_planners(doc: Mapping) -> tuple[PlannerEntry, ...]:
    items = doc.get("planners", [{}])      # one entry of PlannerEntry's defaults
    if not isinstance(items, list) or not items:
        raise ConfigError("planners", "must be a non-empty array of tables ([[planners]])", items)
    d = _defaults(PlannerEntry)
    out = []
    for _, where, t in _tables(items, "planners"):
        _no_unknown(t, ("trajectory", "gaze", "trajectory_params", "gaze_params", "name"), where)
        traj = _string(t, "trajectory", where, d["trajectory"])
        gaze = _string(t, "gaze", where, d["gaze"])
        tp = _table(t, "trajectory_params", where)
        gp = _table(t, "gaze_params", where)
        check_finite_params(tp, f"{where}.trajectory_params")
        check_finite_params(gp, f"{where}.gaze_params")
        name = _string(t, "name", where, d["name"])
        out.append(PlannerEntry(traj, gaze, dict(tp), dict(gp), name))
    labels = [p.label for p in out]
    if len(set(labels)) != len(labels):
        raise ConfigError("planners", "two entries have the same label; give one a distinct name", labels)
    return tuple(out)


def _check_fit(obstacles: ObstacleConfig, world: WorldConfig) -> None:
    """Reject counts whose obstacles cannot fit: total footprint above half the arena (a packing bound)."""
    area = math.prod(world.size[:2]) if world.dims == 2 else math.prod(world.size)
    for n in obstacles.count:
        for r in obstacles.radius:
            rmax = (r.max if isinstance(r, Range) else r) + obstacles.radius_jitter
            fp = math.pi * rmax ** 2 if world.dims == 2 else 4.0 / 3.0 * math.pi * rmax ** 3
            if n * fp > 0.5 * area:
                raise ConfigError("obstacles.count", f"{n} obstacles of radius up to {rmax:g} m cannot fit in the arena", n)
            if 2 * rmax >= min(world.size):
                raise ConfigError("obstacles.radius", "an obstacle must fit in the arena", rmax)


def _check_program_layout(obstacles: ObstacleConfig, world: WorldConfig, static: tuple) -> None:
    """ConfigError unless obstacles.layout = "program" has what the program's maps had: 2D, no static obstacles."""
    if obstacles.layout != "program":
        return
    if world.dims != 2:
        raise ConfigError("obstacles.layout", '"program" draws 2D maps (world.dims = 2)', obstacles.layout)
    if static:
        raise ConfigError("obstacles.layout", '"program" cannot be combined with static_obstacles', obstacles.layout)


def _check_nesting(doc: Any) -> None:
    """ConfigError if tables / arrays nest deeper than limits.MAX_NESTING (iterative: never a RecursionError)."""
    stack = [(doc, 0)]
    while stack:
        node, depth = stack.pop()
        if depth > limits.MAX_NESTING:
            raise ConfigError("scenario", f"nested too deeply (more than {limits.MAX_NESTING} levels of tables and "
                              "arrays)", None, show_value=False)
        if isinstance(node, Mapping):
            stack.extend((v, depth + 1) for v in node.values())
        elif isinstance(node, (list, tuple)):
            stack.extend((v, depth + 1) for v in node)


def _static_distance(s: StaticObstacleConfig, point: tuple[float, ...]) -> float:
    """Signed distance (m) from a point [d] to a static obstacle's surface (negative inside): a pillar is a vertical
    cylinder (distance in x-y), a box a rectangle (2D) or cuboid (3D) turned by yaw_deg about z (the same geometry
    as pbdyn.world.geometry.StaticBody.footprint_distance)."""
    if s.kind == "pillar":
        return math.hypot(point[0] - s.center[0], point[1] - s.center[1]) - s.radius
    rel = [p - c for p, c in zip(point, s.center)]
    yaw = math.radians(s.yaw_deg)
    cy, sy = math.cos(yaw), math.sin(yaw)
    rel[0], rel[1] = cy * rel[0] + sy * rel[1], -sy * rel[0] + cy * rel[1]
    q = [abs(x) - h / 2.0 for x, h in zip(rel, s.size)]
    return math.sqrt(sum(max(x, 0.0) ** 2 for x in q)) + min(max(q), 0.0)


def _check_static_candidates(static: tuple[StaticObstacleConfig, ...], task: TaskConfig, drone: DroneConfig) -> None:
    """ConfigError if a start/goal candidate's MAV overlaps a static obstacle (no trial could start or end there;
    imported worlds refuse the same, pbdyn.world.imported.bodies.check_candidates)."""
    for i, s in enumerate(static):
        for j, c in enumerate(task.candidates):
            if _static_distance(s, c) < drone.radius:
                raise ConfigError(f"static_obstacles[{i}]", f"the MAV at start/goal candidate task.candidates[{j}] "
                                  f"{list(c)} would overlap it", {"kind": s.kind, "center": list(s.center)})


def _check_urdfs(scenario: "Scenario") -> None:
    """Every URDF the scenario names passes pbdyn.urdf.check_urdf (drone.urdf, bodies[i].urdf), at its scale."""
    r = scenario.drone.radius
    named = [("drone.urdf", scenario.drone.urdf, (r, r, r))]
    named += [(f"bodies[{i}].urdf", b.urdf, b.scale) for i, b in enumerate(scenario.bodies)]
    for field_name, name, scale in named:
        path = scenario.resolve_path(name, field_name)
        if not path.is_file():
            raise ConfigError(field_name, "file not found" + ("" if Path(name).is_absolute() else
                              " (relative paths: the scenario's folder, then the bundled urdf/)"), name)
        check_urdf(path, field_name, scale)


def _check_rollout_size(world: WorldConfig, obstacles: ObstacleConfig, bodies: tuple, task: TaskConfig) -> None:
    """A map's rollout (default horizon) must fit limits.MAX_STEPS and limits.MAX_ROLLOUT_BYTES: positions and
    velocities of every obstacle (steps x N x d x 8 bytes x 2), plus an imported world's body poses (steps x B x 7 x
    8 bytes)."""
    steps = (rollout_span_s(world, task) + world.dt) / world.dt + 1
    limits.check_limit("task.start_wait_max_s", "rollout steps (time limit + start wait + dt) / dt", steps,
                       limits.MAX_STEPS, task.start_wait_max_s)
    n = max(max(obstacles.count), len(bodies))
    nbytes = steps * (n * world.dims * 8 * 2 + len(bodies) * 7 * 8)
    limits.check_limit("world.dt", f"bytes for a rollout of {steps:.0f} steps x {n} obstacles", nbytes,
                       limits.MAX_ROLLOUT_BYTES, world.dt)


def with_profile_defaults(doc: Mapping, profile: str) -> Mapping:
    """``doc`` with the omitted fields that ``profile`` sets (PROFILE_DEFAULTS) filled in; given fields win."""
    extra = PROFILE_DEFAULTS.get(profile, {})
    if not extra:
        return doc
    out = dict(doc)
    for (section, key), value in extra.items():
        if not section:
            out.setdefault(key, value)
            continue
        table = out.get(section, {})
        if isinstance(table, Mapping) and key not in table:
            out[section] = {**table, key: value}
    return out


WALL_GAP_MARGIN_M = 0.5
"""The planners' safety margin a structure's wall gap must leave on each side of the MAV disc."""


def _check_wall_gaps(obstacles: ObstacleConfig, drone: DroneConfig) -> None:
    """ConfigError unless every structure's wall gaps pass the MAV disc plus WALL_GAP_MARGIN_M on each side."""
    need = 2.0 * (drone.radius + WALL_GAP_MARGIN_M)
    for st in obstacles.structures:
        if st.walls and st.wall_gap < need:
            raise ConfigError(f"obstacles.structures.{st.name}.wall_gap", f"must be >= {need:g} m (the MAV's "
                              f"diameter plus a {WALL_GAP_MARGIN_M:g} m margin on each side) so that a gap is "
                              "passable", st.wall_gap)



def _utf8(text: str) -> str:
    """``text`` with bytes that are not UTF-8 (os.fsdecode's surrogates, e.g. a file name holding b"\\xff") written
    as escapes ("\\xff"), so that a name taken from a file name can be stored, printed and drawn."""
    return text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")

def parse_scenario(doc: Mapping, source: str = "") -> Scenario:
    """Validate a parsed TOML document into a Scenario."""
    if not isinstance(doc, Mapping):
        raise ConfigError("scenario", "must be a table", doc)
    _check_nesting(doc)
    _no_unknown(doc, ("name", "world", "obstacles", "static_obstacles", "drone", "sensor", "tracking", "task",
                      "planners", "collision_check", "bodies", "profile"), "")
    name = _string(doc, "name", "", _utf8(Path(source).stem) if source else Scenario.DEFAULT_NAME)
    profile = _string(doc, "profile", "", _defaults(Scenario)["profile"], PROFILES)
    doc = with_profile_defaults(doc, profile)
    world = _parse_world(doc)
    bodies = _parse_bodies(doc, world)
    if bodies:
        if "obstacles" in doc:
            raise ConfigError("obstacles", "a world file's obstacles are its [[bodies]]: remove the [obstacles] table",
                              None, show_value=False)
        obstacles = ObstacleConfig(count=(0,))
    else:
        obstacles = _parse_obstacles(doc)
    _check_fit(obstacles, world)
    static = _parse_static(doc, world)
    _check_program_layout(obstacles, world, static)
    drone = _parse_drone(doc)
    sensor = _parse_sensor(doc, world)
    _check_resolution(sensor, obstacles, static)
    tracking = _parse_tracking(doc)
    task = _parse_task(doc, world, drone)
    _check_static_candidates(static, task, drone)
    _check_wall_gaps(obstacles, drone)
    planners = _parse_planners(doc)
    check = _string(doc, "collision_check", "", _defaults(Scenario)["collision_check"], COLLISION_CHECKS)
    _check_rollout_size(world, obstacles, bodies, task)
    if bodies and task.start_rule == "program":
        raise ConfigError("task.start_rule", "\"program\" re-spawns generated obstacles around the start; an imported "
                          "world's bodies cannot move (use \"first_clear\" or \"immediate\")", task.start_rule)
    scenario = Scenario(name, world, obstacles, static, drone, sensor, tracking, task, planners, check, source, bodies,
                        profile)
    _check_urdfs(scenario)
    warn_stopping(scenario, drone.v_max, "drone.v_max")
    return scenario


def load_scenario(path: str | Path) -> Scenario:
    """Load and validate a TOML scenario file, or a bundled scenario named without a path ("quickstart"; an
    existing file wins). Raises ConfigError (missing file, malformed TOML, invalid values)."""
    p = resources.find_scenario(path)
    try:
        doc = tomllib.loads(p.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError("scenario", f"malformed TOML in {p.name}: {exc}", None, show_value=False) from None
    except UnicodeError:
        raise ConfigError("scenario", f"{p.name} is not UTF-8 text", None, show_value=False) from None
    except RecursionError:
        raise ConfigError("scenario", f"nested too deeply ({p.name})", None, show_value=False) from None
    except OSError as exc:
        raise ConfigError("scenario", f"cannot read {p.name} ({exc.strerror or type(exc).__name__})", str(p),
                          ) from None
    return parse_scenario(doc, str(p))
