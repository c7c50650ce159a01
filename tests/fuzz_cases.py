"""Seeded fuzz cases for the CLI contract (tests/test_fuzz.py).

Case ``index`` starts from one of the bundled documents (scenarios/quickstart.toml, spheres_3d.toml,
worlds/warehouse_2d.toml, worlds/mixed_3d.toml) and applies one mutation (sometimes two), drawn by
``numpy.random.default_rng([FUZZ_SEED, index])``:

- ``set``: a field (present, or any documented field that is absent) gets a value of a category: negative, zero,
  nan, inf, huge (1e12, 2**63-1, 1e308), tiny (1e-9), scaled (the value x10, x0.1, x-1, x1000; lists
  element-wise), enum (a valid-looking name), string, bool, float_for_int, empty_list, list, longer/shorter list,
  element (one list element replaced by one of the scalar categories), nested_table, empty_table, long_string,
  control_chars -- drawn with weights by the field's current type (numbers mostly get numeric extremes);
- ``delete``: a field or a whole table removed; ``dup``: a [[table]] entry or a list element duplicated;
- ``unknown_key``: a key no table knows, added to a table;
- ``text``: the TOML text itself broken (truncated, a table header repeated, invalid UTF-8, a NUL byte);
- ``urdf``: (world files) a body's URDF copied into the case folder and broken: box sizes, sphere radii, cylinder
  lengths, origin rpy/xyz, mesh scale or file, missing geometry, broken XML;
- ``motionfn``: (world files) a body's motion becomes one of tests/usercode_motions.py's misbehaving functions;
- ``card``: (no scenario) a file given to ``pbdyn bench --compare``: truncated, foreign (a suite manifest, gzip or
  random bytes, an empty file, a JSON list, a schema name alone), tampered (a card-like document with wrong types),
  deeply nested, or a folder without card.json;
- ``suite``: (no scenario) a copy of the mini suite folder whose suite.json or reference.json.gz is tampered
  (truncated, not JSON, a value changed, the references' digest changed, random bytes, recompressed with a changed
  row, removed), given to ``pbdyn bench straight_line --suite FOLDER``;
- ``flag``: (no scenario) one numeric flag of one command with a huge, negative, NaN or infinite value.

Card, suite and flag cases must be refused: exit 2 with one line, nothing written.

A case's command is ``pbdyn run CASE --json`` (half the cases; a mutated [[planners]] entry is moved to the front,
since run flies the first), ``pbdyn metrics CASE --json --metric density`` or
``pbdyn rollout CASE --out CASE_DIR/out.npz``; in 80 % of the cases world.time_limit is first set to 2 s so valid
cases finish fast (a ``set`` mutation of world.time_limit still wins).

Every mutation has a class, ``op:field:category`` with list indices written ``[]`` (e.g. ``set:world.dt:tiny``,
``urdf:box.size:negative``, ``text:truncate``); tests/test_fuzz.py's KNOWN_OPEN holds fnmatch patterns of classes
whose failures other work is fixing.

    python -m tests.fuzz_cases INDEX            # the case's mutations, command and mutated document
    python -m tests.fuzz_cases INDEX --run      # ... and run it as a subprocess, with the oracle's verdict
"""

from __future__ import annotations

import contextlib
import copy
import json
import math
import os
import re
import sys
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
FUZZ_SEED = 20240612
SHORT_TIME_LIMIT = 2.0

BASES = {
    "quickstart": ROOT / "scenarios" / "quickstart.toml",
    "spheres_3d": ROOT / "scenarios" / "spheres_3d.toml",
    "warehouse_2d": ROOT / "scenarios" / "worlds" / "warehouse_2d.toml",
    "mixed_3d": ROOT / "scenarios" / "worlds" / "mixed_3d.toml",
}

SCHEMA: dict[str, tuple[str, ...]] = {
    "": ("name", "collision_check"),
    "world": ("dims", "size", "dt", "time_limit", "grid_resolution", "flight_height"),
    "obstacles": ("count", "radius", "speed", "radius_jitter", "motion", "maps_per_setup", "root_seed"),
    "obstacles.rvo": ("time_horizon", "wall_time_horizon", "n_headings", "n_speeds", "contact_iterations"),
    "static_obstacles[]": ("kind", "center", "radius", "size", "yaw_deg"),
    "bodies[]": ("name", "urdf", "scale", "position", "rpy_deg", "motion", "velocity", "waypoints", "speed", "params"),
    "drone": ("urdf", "radius", "a_max", "v_max", "yaw_rate_limit"),
    "sensor": ("fov_deg", "vfov_deg", "range", "resolution_deg", "noise_std"),
    "tracking": ("q", "r", "p0_pos", "p0_vel", "drop_pos_var"),
    "task": ("candidates", "goal_radius", "spawn_clearance", "deadlock_steps"),
    "planners[]": ("trajectory", "gaze", "trajectory_params", "gaze_params", "name"),
    "planners[].trajectory_params": ("horizon_s", "n_headings", "n_candidates", "sphere_spacing_deg"),
    "planners[].gaze_params": ("gain", "rate_fraction"),
}
"""Documented fields (docs/scenarios.md "Scenario reference") a ``set`` may create when the base document lacks them."""

CATEGORIES = ("enum", "negative", "zero", "nan", "inf", "huge", "tiny", "scaled", "string", "bool", "float_for_int",
              "empty_list", "list", "longer_list", "shorter_list", "element", "nested_table", "empty_table",
              "long_string", "control_chars")
"""Every value category; a field's draw is weighted by its current type (CATEGORY_WEIGHTS)."""

_WRONG_TYPE = {"string": 1, "bool": 1, "list": 1, "nested_table": 1, "long_string": 0.5, "control_chars": 0.5,
               "enum": 1, "empty_list": 0.5}
CATEGORY_WEIGHTS: dict[str, dict[str, float]] = {
    "number": {"negative": 3, "zero": 3, "nan": 3, "inf": 2, "huge": 4, "tiny": 3, "scaled": 5, "float_for_int": 1,
               **_WRONG_TYPE},
    "list": {"element": 8, "scaled": 5, "longer_list": 2, "shorter_list": 2, "empty_list": 1, "negative": 1,
             "nan": 1, "huge": 1, "string": 1, "nested_table": 1, "list": 1},
    "string": {"enum": 4, "string": 2, "control_chars": 2, "long_string": 1, "zero": 1, "nan": 1, "list": 1,
               "empty_table": 1},
    "table": {"nested_table": 2, "empty_table": 2, "scaled": 3, "string": 1, "zero": 1, "list": 1},
    "absent": {c: 1.0 for c in CATEGORIES},
}
"""Category weights by the kind of the field's current value (a mutation near the valid range reaches deeper)."""


def _kind(v) -> str:
    if v is _MISSING:
        return "absent"
    if isinstance(v, bool) or isinstance(v, str):
        return "string"
    if isinstance(v, (int, float)):
        return "number"
    if isinstance(v, list):
        return "list"
    return "table"


def _category(old, rng: np.random.Generator) -> str:
    w = CATEGORY_WEIGHTS[_kind(old)]
    names = list(w)
    p = np.array([w[n] for n in names], dtype=float)
    return str(rng.choice(names, p=p / p.sum()))


ENUM_STRINGS = ("cvm", "rvo", "static", "constant_velocity", "waypoints", "pillar", "box", "sphere", "sampled",
                "swept", "local_primitives", "global_primitives", "straight_line", "mpc", "lookahead", "fullrange",
                "owl", "finean", "rotating", "lookgoal", "lookgoal_unexplored", "pbdyn.world.motions:circle", "pbdyn.world.motions:bob",
                "quadrotor.urdf", "sphere.urdf", "pillar.urdf", "box.urdf")
"""Valid-looking strings for the ``enum`` category (names of motions, kinds, planners, bundled files)."""

MOTION_FUNCTIONS = ("returns_string", "returns_complex", "returns_none", "returns_short", "returns_nan",
                    "returns_bool", "returns_zero_quat", "returns_huge_quat", "returns_huge_int", "returns_bad_float",
                    "raises_system_exit", "raises_generator_exit", "raises_custom_base", "raises_value_error",
                    "raises_unprintable", "prints", "prints_c_level", "good")

URDF_KINDS = ("box.size", "sphere.radius", "cylinder.radius", "cylinder.length", "origin.rpy", "origin.xyz",
              "mesh.scale", "mesh.filename", "no_geometry", "no_collision", "broken_xml", "empty_file")
URDF_VALUES = ("negative", "zero", "nan", "inf", "huge", "tiny", "string", "short")

TEXT_KINDS = ("truncate", "dup_header", "invalid_utf8", "nul_byte")

COMMANDS = ("run", "metrics", "rollout")

MINI_SUITE = ROOT / "scenarios" / "suites" / "pbdyn-2d-mini"
CARD_KINDS = ("truncated_manifest", "manifest", "gzip", "random_bytes", "empty", "json_list", "schema_only",
              "wrong_types", "deep_nesting", "huge_number", "folder", "nul_bytes")
SUITE_KINDS = ("manifest:truncate", "manifest:not_json", "manifest:value", "manifest:digest", "manifest:remove",
               "reference:truncate", "reference:random_bytes", "reference:row", "reference:remove")
_GEN = ["generate", "--metric", "density", "--target", "1", "--tolerance", "0.1", "--out", "{dir}/g.toml"]
NUMERIC_FLAGS = {
    ("run", "--map"): ["run", "quickstart"], ("run", "--vmax"): ["run", "quickstart"],
    ("replay", "--fps"): ["replay", "{dir}/t.npz", "--out", "{dir}/r.gif"],
    ("replay", "--every"): ["replay", "{dir}/t.npz", "--out", "{dir}/r.gif"],
    ("rollout", "--map"): ["rollout", "quickstart", "--out", "{dir}/out.npz"],
    ("rollout", "--horizon"): ["rollout", "quickstart", "--out", "{dir}/out.npz"],
    ("metrics", "--map"): ["metrics", "quickstart"], ("demo", "--maps"): ["demo", "quickstart"],
    ("demo", "--pairs"): ["demo", "quickstart"],
    ("batch", "--workers"): ["batch", "quickstart", "--out", "{dir}/b.db"],
    ("batch", "--limit"): ["batch", "quickstart", "--out", "{dir}/b.db"],
    ("batch", "--lockstep"): ["batch", "quickstart", "--out", "{dir}/b.db"],
    ("evaluate", "--bootstrap"): ["evaluate", "{dir}/none.db"],
    ("generate", "--target"): _GEN[:4] + _GEN[6:], ("generate", "--tolerance"): _GEN[:6] + _GEN[8:],
    ("generate", "--success"): ["generate", "--tolerance", "0.1", "--out", "{dir}/g.toml"],
    **{("generate", f): _GEN for f in ("--count", "--dims", "--obstacles", "--radius", "--speed", "--seed",
                                        "--workers")},
    ("calibrate", "--map"): ["calibrate", "quickstart"], ("calibrate", "--workers"): ["calibrate", "quickstart"],
    ("bench", "--workers"): ["bench", "straight_line", "--out", "{dir}/bench"],
    ("bench", "--failures"): ["bench", "straight_line", "--out", "{dir}/bench"],
}
"""Every numeric flag of every command, with the rest of a command line that is valid."""
FLAG_VALUES = {"nan": ["nan", "NaN", "-nan"], "inf": ["inf", "-inf", "Infinity"], "negative": ["-1", "-1e300"],
               "huge": ["1e400", str(2 ** 64), "9" * 40, "1e10", "-1e10"]}
SIGNED_FLAGS = {("generate", "--target")}
"""Flags a negative value is valid for (huge values beyond the limits, NaN and infinity only)."""


# ------------------------------------------------------------------------------------------------ TOML writer
_BARE = re.compile(r"^[A-Za-z0-9_-]+$")


def _key(k: str) -> str:
    return k if _BARE.match(k) else _string(k)


def _string(s: str) -> str:
    out = ['"']
    for c in s:
        if c == '"':
            out.append('\\"')
        elif c == "\\":
            out.append("\\\\")
        elif ord(c) < 0x20 or ord(c) == 0x7F:
            out.append(f"\\u{ord(c):04x}")
        else:
            out.append(c)
    out.append('"')
    return "".join(out)


def _value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        r = repr(v)
        return r if any(ch in r for ch in ".en") else r + ".0"
    if isinstance(v, str):
        return _string(v)
    if isinstance(v, list):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{_key(k)} = {_value(x)}" for k, x in v.items()) + " }" if v else "{}"
    raise TypeError(f"cannot write {type(v).__name__} as TOML")


def to_toml(doc: dict) -> str:
    """``doc`` as TOML text (top-level scalars, then [tables], then [[arrays of tables]]; nested values inline)."""
    lines, tables, arrays = [], [], []
    for k, v in doc.items():
        if isinstance(v, dict):
            tables.append((k, v))
        elif isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
            arrays.append((k, v))
        else:
            lines.append(f"{_key(k)} = {_value(v)}")
    for k, v in tables:
        lines.append(f"\n[{_key(k)}]")
        lines += [f"{_key(a)} = {_value(b)}" for a, b in v.items()]
    for k, items in arrays:
        for item in items:
            lines.append(f"\n[[{_key(k)}]]")
            lines += [f"{_key(a)} = {_value(b)}" for a, b in item.items()]
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------------------------ cases
@dataclass
class Case:
    """One fuzz case: what was done (``mutations``, each ``(class, detail)``), the command, the files."""

    index: int
    base: str
    command: str
    doc: dict | None = None
    text: bytes = b""
    urdfs: dict[str, str] = field(default_factory=dict)   # file name in the case folder -> text
    mutations: list[tuple[str, str]] = field(default_factory=list)
    files: dict[str, bytes] = field(default_factory=dict)  # card, suite and flag cases: path in the folder -> bytes
    command_line: list[str] | None = None                 # card, suite and flag cases: argv, "{dir}": the folder

    @property
    def must_refuse(self) -> bool:
        """Card, suite and flag cases are bad input: exit 2 only."""
        return self.command_line is not None

    @property
    def classes(self) -> list[str]:
        return [c for c, _ in self.mutations]

    def write(self, folder: Path) -> Path:
        """Write the case's files into ``folder``; returns the scenario path."""
        folder.mkdir(parents=True, exist_ok=True)
        for name, text in self.urdfs.items():
            (folder / name).write_text(text)
        for name, data in self.files.items():
            (folder / name).parent.mkdir(parents=True, exist_ok=True)
            if data is not None:
                (folder / name).write_bytes(data)
        path = folder / "case.toml"
        path.write_bytes(self.text)
        return path

    def argv(self, path: Path, folder: Path) -> list[str]:
        if self.command_line is not None:
            return [a.replace("{dir}", str(folder)) for a in self.command_line]
        if self.command == "run":
            return ["run", str(path), "--json"]
        if self.command == "metrics":
            return ["metrics", str(path), "--json", "--metric", "density"]
        return ["rollout", str(path), "--out", str(folder / "out.npz")]

    def describe(self) -> str:
        muts = "; ".join(f"{c} [{d}]" for c, d in self.mutations)
        return f"fuzz case {self.index} (base {self.base}, command {self.command}): {muts}"


def _absolute_bodies(doc: dict, base_path: Path) -> None:
    """Point world bodies' URDFs at absolute paths (the case is written elsewhere)."""
    for body in doc.get("bodies", []):
        u = body.get("urdf")
        if isinstance(u, str):
            local = base_path.parent / u
            body["urdf"] = str(local if local.is_file() else ROOT / "urdf" / u)


def _paths(doc: dict) -> list[tuple]:
    """Every existing field path (tables, values, list elements one level deep) and every schema field."""
    out: list[tuple] = []

    def walk(node, path):
        if isinstance(node, dict):
            for k, v in node.items():
                out.append(path + (k,))
                walk(v, path + (k,))
        elif isinstance(node, list) and node and all(isinstance(x, dict) for x in node):
            for i, v in enumerate(node):
                out.append(path + (i,))
                walk(v, path + (i,))

    walk(doc, ())
    existing = set(out)
    for table, keys in SCHEMA.items():
        if table.startswith("obstacles") and "bodies" in doc:
            continue  # a world file has no [obstacles]: rejected at once, already covered by set:obstacles
        for prefix in _expand(doc, table):
            for k in keys:
                p = prefix + (k,)
                if p not in existing:
                    out.append(p)
    return out


def _expand(doc: dict, table: str) -> list[tuple]:
    """Concrete paths of a SCHEMA table name ("planners[].gaze_params" -> ("planners", 0, "gaze_params"), ...)."""
    if table == "":
        return [()]
    prefixes: list[tuple] = [()]
    for part in table.split("."):
        nxt = []
        for pre in prefixes:
            if part.endswith("[]"):
                name = part[:-2]
                node = _get(doc, pre + (name,))
                if isinstance(node, list):
                    nxt += [pre + (name, i) for i in range(len(node))]
            else:
                nxt.append(pre + (part,))
        prefixes = nxt
    return prefixes


_MISSING = object()


def _get(doc, path):
    node = doc
    for p in path:
        if isinstance(p, int):
            if not isinstance(node, list) or p >= len(node):
                return _MISSING
        elif not isinstance(node, dict) or p not in node:
            return _MISSING
        node = node[p]
    return node


def _parent(doc, path, create: bool):
    node = doc
    for p in path[:-1]:
        if isinstance(p, int):
            node = node[p]
        else:
            if p not in node or not isinstance(node[p], (dict, list)):
                if not create:
                    return None
                node[p] = {}
            node = node[p]
    return node


def path_name(path: tuple) -> str:
    """("bodies", 3, "scale") -> "bodies[].scale" (the class name of a field)."""
    s = ""
    for p in path:
        s += "[]" if isinstance(p, int) else (f".{p}" if s else p)
    return s


def _scalar(cat: str, old, rng: np.random.Generator):
    is_int = isinstance(old, int) and not isinstance(old, bool)
    if cat == "negative":
        return -1 if is_int else float(rng.choice([-1.0, -0.5, -1e3]))
    if cat == "zero":
        return 0 if is_int else 0.0
    if cat == "nan":
        return float("nan")
    if cat == "inf":
        return float(rng.choice([math.inf, -math.inf]))
    if cat == "huge":
        return [1e12, 2 ** 63 - 1, 1e308][int(rng.integers(3))]
    if cat == "tiny":
        return 1e-9
    if cat == "string":
        return str(rng.choice(["abc", "1.0", "", "quickstart", "none"]))
    if cat == "bool":
        return bool(rng.integers(2))
    if cat == "float_for_int":
        return 2.5
    if cat == "long_string":
        return "x" * 5000
    if cat == "control_chars":
        return "a\x00b\x1b[31m\nc\r\u2028d\x7f"
    raise ValueError(cat)


def _mutated_value(cat: str, old, rng: np.random.Generator):
    if cat == "scaled":
        factor = float(rng.choice([10.0, 0.1, -1.0, 1000.0]))

        def scale(x):
            if isinstance(x, bool):
                return x
            if isinstance(x, int):
                return int(x * factor) if abs(x * factor) < 2 ** 62 else x
            if isinstance(x, float):
                return x * factor
            if isinstance(x, list):
                return [scale(y) for y in x]
            if isinstance(x, dict):
                return {k: scale(y) for k, y in x.items()}
            return x
        return scale(old)
    if cat == "enum":
        return str(rng.choice(ENUM_STRINGS))
    if cat == "empty_list":
        return []
    if cat == "list":
        return [1.0, 2.0] if not isinstance(old, list) else [old]
    if cat == "longer_list":
        return (old + [old[-1]]) if isinstance(old, list) and old else [old, old]
    if cat == "shorter_list":
        return old[:-1] if isinstance(old, list) and old else []
    if cat == "element":
        if isinstance(old, list) and old:
            new = copy.deepcopy(old)
            i = int(rng.integers(len(new)))
            sub = str(rng.choice(["negative", "zero", "nan", "inf", "huge", "tiny", "string", "bool"]))
            if isinstance(new[i], list) and new[i]:
                j = int(rng.integers(len(new[i])))
                new[i][j] = _scalar(sub, new[i][j], rng)
            else:
                new[i] = _scalar(sub, new[i], rng)
            return new
        return [_scalar("nan", 0.0, rng)]
    if cat == "nested_table":
        return {"a": {"b": 1}}
    if cat == "empty_table":
        return {}
    return _scalar(cat, old, rng)


def _mutate_doc(doc: dict, rng: np.random.Generator) -> tuple[str, str]:
    """One structural mutation of ``doc`` in place; returns (class, detail)."""
    op = str(rng.choice(["set"] * 8 + ["delete", "dup", "unknown_key"]))
    if op == "set":
        paths = _paths(doc)
        path = paths[int(rng.integers(len(paths)))]
        old = _get(doc, path)
        cat = _category(old, rng)
        new = _mutated_value(cat, 1.0 if old is _MISSING else copy.deepcopy(old), rng)
        parent = _parent(doc, path, create=True)
        parent[path[-1]] = new
        _first_planner(doc, path)
        return f"set:{path_name(path)}:{cat}", f"{path_name(path)} = {_short(new)} (was {_short(old)})"
    if op == "delete":
        paths = [p for p in _paths(doc) if _get(doc, p) is not _MISSING]
        path = paths[int(rng.integers(len(paths)))]
        parent = _parent(doc, path, create=False)
        del parent[path[-1]]
        return f"delete:{path_name(path)}", f"deleted {'.'.join(map(str, path))}"
    if op == "dup":
        lists = [p for p in _paths(doc) if isinstance(_get(doc, p), list) and _get(doc, p)]
        if not lists:
            return _mutate_doc(doc, rng)
        path = lists[int(rng.integers(len(lists)))]
        node = _get(doc, path)
        i = int(rng.integers(len(node)))
        node.insert(i, copy.deepcopy(node[i]))
        return f"dup:{path_name(path)}", f"duplicated {'.'.join(map(str, path))}[{i}]"
    tables = [()] + [p for p in _paths(doc) if isinstance(_get(doc, p), dict)]
    path = tables[int(rng.integers(len(tables)))]
    _get(doc, path)["zz_unknown"] = 1.0
    return f"unknown_key:{path_name(path) or '<top>'}", f"{'.'.join(map(str, path)) or '<top>'}.zz_unknown = 1.0"


def _first_planner(doc: dict, path: tuple) -> None:
    """A mutated [[planners]] entry moves to the front (``pbdyn run`` flies the first entry)."""
    if len(path) >= 2 and path[0] == "planners" and isinstance(path[1], int) and isinstance(doc.get("planners"), list):
        entries = doc["planners"]
        entries.insert(0, entries.pop(path[1]))


def _short(v) -> str:
    if v is _MISSING:
        return "absent"
    text = repr(v)
    return text if len(text) <= 60 else text[:57] + "..."


def _mutate_text(text: str, rng: np.random.Generator) -> tuple[bytes, tuple[str, str]]:
    kind = str(rng.choice(TEXT_KINDS))
    data = text.encode("utf-8")
    if kind == "truncate":
        cut = int(rng.integers(1, max(2, len(data))))
        return data[:cut], (f"text:{kind}", f"cut at byte {cut} of {len(data)}")
    if kind == "dup_header":
        headers = [m.group(0) for m in re.finditer(r"^\[[a-z_]+\]$", text, flags=re.M)]
        if headers:
            h = headers[int(rng.integers(len(headers)))]
            return (text + f"\n{h}\n").encode(), (f"text:{kind}", f"{h} repeated")
        return (text + "\n[world]\n[world]\n").encode(), (f"text:{kind}", "[world] twice")
    if kind == "invalid_utf8":
        pos = int(rng.integers(len(data)))
        return data[:pos] + b"\xff\xfe" + data[pos:], (f"text:{kind}", f"0xff 0xfe at byte {pos}")
    pos = int(rng.integers(len(data)))
    return data[:pos] + b"\x00" + data[pos:], (f"text:{kind}", f"NUL at byte {pos}")


_URDF_BAD = {"negative": "-1", "zero": "0", "nan": "nan", "inf": "inf", "huge": "1e12", "tiny": "1e-9",
             "string": "abc", "short": ""}


def _mutate_urdf(doc: dict, rng: np.random.Generator, urdfs: dict[str, str]) -> tuple[str, str]:
    bodies = doc.get("bodies") or []
    i = int(rng.integers(len(bodies)))
    src = Path(bodies[i]["urdf"])
    if str(src) in urdfs:
        text = urdfs[str(src)]
    else:
        src = src if src.is_absolute() else ROOT / "urdf" / src
        src = src if src.is_file() else ROOT / "urdf" / "box.urdf"   # an earlier mutation named no file
        text = src.read_text()
    text = re.sub(r'filename="([^"]+)"', lambda m: f'filename="{(src.parent / m.group(1)).resolve()}"', text)
    kind = str(rng.choice(URDF_KINDS))
    val = str(rng.choice(URDF_VALUES))
    bad = _URDF_BAD[val]
    geometry = {"box.size": '<box size="{v} {v} {v}"/>', "sphere.radius": '<sphere radius="{v}"/>',
                "cylinder.radius": '<cylinder radius="{v}" length="1"/>',
                "cylinder.length": '<cylinder radius="0.5" length="{v}"/>'}
    if kind in geometry:
        if val == "short" and kind == "box.size":
            shape = '<box size="1 1"/>'
        else:
            one = [bad, "1", "1"] if rng.integers(2) else [bad] * 3
            shape = geometry[kind].replace("{v} {v} {v}", " ".join(one)).replace("{v}", bad)
        text = re.sub(r"<geometry>.*?</geometry>", f"<geometry>{shape}</geometry>", text, count=1, flags=re.S)
    elif kind in ("origin.rpy", "origin.xyz"):
        attr = kind.split(".")[1]
        vec = f"{bad} 0 0" if val != "short" else "0 0"
        text = re.sub(r"(<collision>\s*<origin[^>]*?)" + attr + r'="[^"]*"', rf'\g<1>{attr}="{vec}"', text, count=1)
    elif kind == "mesh.scale":
        vec = f"{bad} 1 1" if val != "short" else "1 1"
        shape = f'<mesh filename="{(ROOT / "scenarios" / "worlds" / "meshes" / "gem.obj")}" scale="{vec}"/>'
        text = re.sub(r"<geometry>.*?</geometry>", f"<geometry>{shape}</geometry>", text, count=1, flags=re.S)
    elif kind == "mesh.filename":
        name = str(rng.choice(["missing.obj", "", "case.toml", "/dev/null"]))
        text = re.sub(r"<geometry>.*?</geometry>", f'<geometry><mesh filename="{name}"/></geometry>', text, count=1,
                      flags=re.S)
        val = name or "empty"
    elif kind == "no_geometry":
        text = re.sub(r"<collision>.*?</collision>", "<collision><origin xyz=\"0 0 0\"/></collision>", text, count=1,
                      flags=re.S)
        val = "-"
    elif kind == "no_collision":
        text = re.sub(r"<collision>.*?</collision>", "", text, flags=re.S)
        val = "-"
    elif kind == "broken_xml":
        text = text[: int(rng.integers(10, len(text) - 10))]
        val = "-"
    else:
        text = ""
        val = "-"
    name = f"body{i}.urdf"
    urdfs[name] = text
    bodies[i]["urdf"] = name
    return f"urdf:{kind}:{val}", f"bodies[{i}] ({src.name}) {kind} = {val}"


def _card_case(case: Case, rng: np.random.Generator) -> None:
    from pbdyn.benchmark.card import CARD_SCHEMA

    kind = str(rng.choice(CARD_KINDS))
    manifest = (MINI_SUITE / "suite.json").read_bytes()
    data = {"truncated_manifest": manifest[: int(rng.integers(1, len(manifest)))], "manifest": manifest,
            "gzip": (MINI_SUITE / "reference.json.gz").read_bytes()[:4096],
            "random_bytes": rng.bytes(int(rng.integers(1, 2048))), "empty": b"", "json_list": b"[1, 2, 3]",
            "schema_only": json.dumps({"schema": CARD_SCHEMA}).encode(),
            "wrong_types": json.dumps({"schema": CARD_SCHEMA, "suite": "x", "planner": 1, "success": [],
                                       "levels": {"a": None}}).encode(),
            "deep_nesting": b"[" * 100_000 + b"]" * 100_000,
            "huge_number": b'{"schema": "' + CARD_SCHEMA.encode() + b'", "x": 1e999}',
            "nul_bytes": b'{"schema": "pbdyn-\x00card/2"}'}.get(kind)
    if kind == "folder":
        case.files["cards/notes.txt"] = b"no card here\n"
        target = "{dir}/cards"
    else:
        case.files["card.json"] = data
        target = "{dir}/card.json"
    others = ["{dir}/card.json"] if kind == "folder" and rng.integers(2) else []
    case.command_line = ["bench", "--compare", target, *others, "--json"]
    case.mutations.append((f"card:{kind}", f"bench --compare {target}"))


def _suite_case(case: Case, rng: np.random.Generator) -> None:
    import gzip

    kind = str(rng.choice(SUITE_KINDS))
    files = {f"suite/{p.name}": p.read_bytes() for p in MINI_SUITE.iterdir() if p.is_file()}
    what, how = kind.split(":")
    name = "suite/suite.json" if what == "manifest" else "suite/reference.json.gz"
    data = files[name]
    if how == "truncate":
        files[name] = data[: int(rng.integers(1, len(data)))]
    elif how == "not_json":
        files[name] = b"suite = 'not json'\n"
    elif how == "random_bytes":
        files[name] = rng.bytes(int(rng.integers(1, 4096)))
    elif how == "remove":
        files[name] = None
    elif how == "digest":
        doc = json.loads(data)
        doc["references_sha256"] = "0" * 64
        files[name] = json.dumps(doc).encode()
    elif how == "value":
        doc = json.loads(data)
        key = str(rng.choice(["name", "dims", "speeds", "levels", "maps"]))
        doc[key] = {"name": "pbdyn-2d-other", "dims": 3, "speeds": [6.0], "levels": [], "maps": []}[key]
        files[name] = json.dumps(doc).encode()
    else:   # a changed row in the references, recompressed
        text = gzip.decompress(data).decode()
        for old, new in (('"success"', '"collision"'), ('"outcome": "success"', '"outcome": "timeout"'), ("0", "1")):
            if old in text:
                text = text.replace(old, new, 1)
                break
        files[name] = gzip.compress(text.encode(), mtime=0)
    case.files = {k: v for k, v in files.items()}
    case.command_line = ["bench", "straight_line", "--suite", "{dir}/suite", "--out", "{dir}/bench", "--workers", "1"]
    case.mutations.append((f"suite:{kind}", f"{name} {how}"))


def _flag_case(case: Case, rng: np.random.Generator) -> None:
    keys = sorted(NUMERIC_FLAGS)
    command, flag = keys[int(rng.integers(len(keys)))]
    cats = [c for c in FLAG_VALUES if not (c == "negative" and (command, flag) in SIGNED_FLAGS)]
    cat = str(rng.choice(cats))
    value = str(rng.choice(FLAG_VALUES[cat]))
    case.command_line = [*NUMERIC_FLAGS[(command, flag)], f"{flag}={value}"]
    case.mutations.append((f"flag:{command}{flag}:{cat}", f"pbdyn {command} {flag}={value}"))


def make_case(index: int) -> Case:
    """Fuzz case ``index`` (deterministic)."""
    rng = np.random.default_rng([FUZZ_SEED, index])
    other = np.random.default_rng([FUZZ_SEED, index, 1])   # the classes added later leave the others' draws alone
    r = other.random()
    if r < 0.12:
        kind, build = [("card", _card_case), ("suite", _suite_case), ("flag", _flag_case)][int(r / 0.04)]
        case = Case(index, kind, kind)
        build(case, other)
        return case
    base = str(rng.choice(list(BASES)))
    doc = tomllib.loads(BASES[base].read_text())
    _absolute_bodies(doc, BASES[base])
    command = str(rng.choice(COMMANDS, p=[0.5, 0.25, 0.25]))
    case = Case(index, base, command)
    if rng.random() < 0.8:
        doc.setdefault("world", {})["time_limit"] = SHORT_TIME_LIMIT
    is_world = "bodies" in doc
    n = 1 if rng.random() < 0.85 else 2
    text_mutation = None
    for _ in range(n):
        r = rng.random()
        if r < 0.06:
            text_mutation = True
        elif is_world and r < 0.22 and isinstance(doc.get("bodies"), list) and doc["bodies"] and all(
                isinstance(b, dict) and isinstance(b.get("urdf"), str) for b in doc["bodies"]):
            case.mutations.append(_mutate_urdf(doc, rng, case.urdfs))
        elif is_world and r < 0.30 and isinstance(doc.get("bodies"), list) and doc["bodies"] and all(
                isinstance(b, dict) for b in doc["bodies"]):
            bodies = doc["bodies"]
            i = int(rng.integers(len(bodies)))
            fn = str(rng.choice(MOTION_FUNCTIONS))
            body = bodies[i]
            for k in ("velocity", "waypoints", "speed", "params"):
                body.pop(k, None)
            body["motion"] = f"tests.usercode_motions:{fn}"
            case.mutations.append((f"motionfn:{fn}", f"bodies[{i}].motion = tests.usercode_motions:{fn}"))
        else:
            for _attempt in range(20):  # a draw that does not fit the document (after an earlier mutation): again
                trial = copy.deepcopy(doc)
                try:
                    mut = _mutate_doc(trial, rng)
                except (TypeError, KeyError, IndexError, AttributeError, ValueError):
                    continue
                doc = trial
                case.mutations.append(mut)
                break
    text = to_toml(doc)
    if text_mutation:
        data, mut = _mutate_text(text, rng)
        case.mutations.append(mut)
        case.text = data
    else:
        case.text = text.encode("utf-8")
    case.doc = doc
    return case


# ------------------------------------------------------------------------------------------------ oracle
@dataclass
class Outcome:
    """What one case did: exit status, stdout, stderr, wall time (s), the files left in its folder."""

    code: object
    stdout: str
    stderr: str
    seconds: float
    leftovers: list[str]
    out_exists: bool
    warnings: list[str] = field(default_factory=list)
    timed_out: bool = False
    exception: BaseException | None = None


def shown_warnings(caught) -> list[str]:
    """The recorded warnings a user would see (Python's default filters hide _SAFE_WARNINGS), one line each."""
    return [f"{w.category.__name__}: {w.message} ({Path(w.filename).name}:{w.lineno})" for w in caught
            if not issubclass(w.category, _SAFE_WARNINGS)]


def exit2_problem(stdout: str, stderr: str) -> str | None:
    """What is wrong with an exit-2 run's streams (stderr: one "pbdyn: error:" line, documented warning lines may
    precede it; stdout: empty), or None."""
    lines = [line for line in stderr.splitlines() if not line.startswith("pbdyn: warning: ")]
    if len(lines) != 1 or not lines[0].startswith("pbdyn: error:"):
        return f"exit 2 but stderr is not one 'pbdyn: error:' line: {stderr[:400]!r}"
    if stdout:
        return f"exit 2 with output on stdout: {stdout[:200]!r}"
    return None


def _strict_json(text: str):
    def bad_constant(name):
        raise ValueError(f"{name} is not JSON")
    return json.loads(text, parse_constant=bad_constant)


def basic_problem(out: Outcome, time_bound_s: float) -> str | None:
    """What breaks the contract whatever the exit: too slow, a warning, a traceback; or None."""
    if out.timed_out or out.seconds > time_bound_s:
        return f"took {out.seconds:.1f} s (bound {time_bound_s:g} s)"
    if out.warnings:
        return f"warning: {out.warnings[0]}"
    if "Traceback" in out.stderr:
        return "traceback on stderr"
    return None


def verdict(case: Case, out: Outcome, time_bound_s: float) -> str | None:
    """None if the case kept the CLI contract, else what broke."""
    problem = basic_problem(out, time_bound_s)
    if problem:
        return problem
    if out.code == 0 and case.must_refuse:
        return f"exit 0 for bad input: {out.stdout[:200]!r}"
    if out.code == 0:
        if case.command == "rollout":
            if not out.out_exists:
                return "exit 0 but no rollout file"
            return None
        try:
            _strict_json(out.stdout)
        except ValueError as exc:
            return f"exit 0 but stdout is not one JSON document ({exc}): {out.stdout[:200]!r}"
        if re.search(r"\bWarning\b", out.stderr):
            return f"exit 0 with a warning on stderr: {out.stderr.strip()[:300]!r}"
        return None
    if out.code == 2:   # a documented warning (e.g. a MAV speed that cannot stop in time) may precede the error
        problem = exit2_problem(out.stdout, out.stderr)
        if problem:
            return problem
        if out.out_exists:
            return "exit 2 but the --out file exists"
        if out.leftovers:
            return f"exit 2 left files behind: {out.leftovers}"
        return None
    return f"exit {out.code}: {out.stderr.strip()[-400:]!r}"


CACHE_DIR = "cache"
"""Each case has its own PBDYN_CACHE inside its folder, so a case's result never depends on the cases before it."""


def expected_files(case: Case) -> set[str]:
    return {"case.toml", CACHE_DIR, *case.urdfs, *(name.split("/")[0] for name in case.files)}


def run_subprocess(case: Case, folder: Path, *, timeout_s: float = 60.0, memory_bytes: int = 4 << 30,
                   env: dict | None = None) -> Outcome:
    """Run the case as a real ``python -m pbdyn.cli`` child with an address-space limit and a wall-clock limit."""
    import resource
    import subprocess
    import time

    path = case.write(folder)

    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (memory_bytes, memory_bytes))

    full_env = dict(os.environ)
    full_env["PBDYN_CACHE"] = str(folder / CACHE_DIR)
    full_env.update(env or {})
    full_env.pop("PBDYN_DEBUG", None)
    t0 = time.monotonic()
    try:
        proc = subprocess.run([sys.executable, "-m", "pbdyn.cli", *case.argv(path, folder)], capture_output=True,
                              text=True, errors="replace", timeout=timeout_s, cwd=ROOT, env=full_env,
                              preexec_fn=limit)
        code, stdout, stderr, timed_out = proc.returncode, proc.stdout, proc.stderr, False
    except subprocess.TimeoutExpired as exc:
        code, stdout, stderr, timed_out = None, str(exc.stdout or ""), str(exc.stderr or ""), True
    seconds = time.monotonic() - t0
    out_file = folder / "out.npz"
    leftovers = sorted(set(os.listdir(folder)) - expected_files(case) - {"out.npz"})
    return Outcome(code, stdout, stderr, seconds, leftovers, out_file.exists(), [], timed_out)


class CaseTimeout(KeyboardInterrupt):
    """Raised by the in-process runner's alarm (a KeyboardInterrupt, so pbdyn lets it through user-code guards)."""


_SAFE_WARNINGS = (DeprecationWarning, PendingDeprecationWarning, ImportWarning, ResourceWarning)
"""Categories Python's default filters hide from users; any other warning fails a case."""


def _vm_size() -> int | None:
    """This process's virtual memory size (bytes; None where /proc is not available)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmSize:"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


@contextlib.contextmanager
def _memory_headroom(memory_bytes: int):
    """Limit this process's address space to its current size + ``memory_bytes`` for the duration (Linux), so a
    case that tries to allocate too much gets a MemoryError (a failure) instead of exhausting the machine."""
    import resource

    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    vm = _vm_size()
    if vm is None or (hard != resource.RLIM_INFINITY and vm + memory_bytes > hard):
        yield
        return
    resource.setrlimit(resource.RLIMIT_AS, (vm + memory_bytes, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


def run_in_process(case: Case, folder: Path, *, timeout_s: float = 60.0, memory_bytes: int = 4 << 30) -> Outcome:
    """Run the case through ``pbdyn.cli.main`` in this process (stdout and stderr captured, every warning
    recorded, an interval timer bounding its wall time, the address space bounded to its size at the start +
    ``memory_bytes``)."""
    import io
    import signal
    import time
    import warnings

    from pbdyn import cli

    path = case.write(folder)
    out, err = io.StringIO(), io.StringIO()
    fired = []

    def on_alarm(signum, frame):
        fired.append(True)
        raise CaseTimeout(f"case {case.index} ran past {timeout_s:g} s")

    old_handler = signal.signal(signal.SIGALRM, on_alarm)
    old_streams = sys.stdout, sys.stderr
    old_cache = os.environ.get("PBDYN_CACHE")
    os.environ["PBDYN_CACHE"] = str(folder / CACHE_DIR)
    t0 = time.monotonic()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sys.stdout, sys.stderr = out, err
        signal.setitimer(signal.ITIMER_REAL, timeout_s)
        try:
            with _memory_headroom(memory_bytes):
                code = cli.main(case.argv(path, folder))
        except SystemExit as exc:
            code = exc.code
        except CaseTimeout:
            code = None
        except BaseException as exc:  # anything escaping main breaks the contract
            code = f"{type(exc).__name__} escaped main: {exc}"
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0.0)
            signal.signal(signal.SIGALRM, old_handler)
            sys.stdout, sys.stderr = old_streams
            if old_cache is None:
                os.environ.pop("PBDYN_CACHE", None)
            else:
                os.environ["PBDYN_CACHE"] = old_cache
    seconds = time.monotonic() - t0
    shown = shown_warnings(caught)
    leftovers = sorted(set(os.listdir(folder)) - expected_files(case) - {"out.npz"})
    return Outcome(code, out.getvalue(), err.getvalue(), seconds, leftovers, (folder / "out.npz").exists(), shown,
                   bool(fired))


def main(argv: list[str]) -> int:
    if not argv or not argv[0].isdigit():
        print(__doc__)
        return 2
    case = make_case(int(argv[0]))
    print(f"# {case.describe()}")
    for name, text in case.urdfs.items():
        print(f"# --- {name}:\n" + "\n".join("# " + line for line in text.splitlines()))
    sys.stdout.write(case.text.decode("utf-8", errors="replace"))
    if "--run" in argv:
        import tempfile
        with tempfile.TemporaryDirectory(prefix="pbdyn-fuzz-") as tmp:
            out = run_subprocess(case, Path(tmp))
            print(f"# exit {out.code} in {out.seconds:.2f} s; stdout {out.stdout[:300]!r}; stderr "
                  f"{out.stderr[-1000:]!r}")
            print(f"# verdict: {verdict(case, out, 60.0) or 'ok'}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
