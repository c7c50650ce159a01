"""One source of truth for scenario defaults: the dataclass fields of pbdyn.config.

Checks that the README's "Scenario reference" table lists every scenario key with the dataclass default (and the
default a parsed empty scenario resolves to), and that the parsers write no default of their own.
"""

from __future__ import annotations

import ast
import dataclasses
import re
import tomllib
from pathlib import Path

import pytest

from pbdyn import config as C
from pbdyn.config.model import _defaults
from pbdyn.motion.rvo import RVOParams

ROOT = Path(__file__).resolve().parents[1]

SECTIONS = {"": C.Scenario, "world": C.WorldConfig, "obstacles": C.ObstacleConfig, "obstacles.rvo": RVOParams,
            "obstacles.structures.name": C.StructureConfig,
            "static_obstacles": C.StaticObstacleConfig, "drone": C.DroneConfig, "sensor": C.SensorConfig,
            "tracking": C.TrackingConfig, "task": C.TaskConfig, "planners": C.PlannerEntry}
"""README table section -> the dataclass whose fields it documents."""

NOT_KEYS = {("", "world"), ("", "obstacles"), ("", "static_obstacles"), ("", "drone"), ("", "sensor"),
            ("", "tracking"), ("", "task"), ("", "planners"), ("", "bodies"), ("", "source"),
            ("obstacles", "rvo"), ("obstacles", "grid_order"), ("obstacles.rvo", "neighbour_dist"),
            ("obstacles", "structures"), ("obstacles.structures.name", "name")}
"""Fields that are no scalar key of their section: sub-tables (own sections; bodies: docs/scenarios.md "Imported worlds"),
the source path, the grid order (the keys' file order), RVO's neighbour_dist (Python API only), the structures'
tables (their own section) and a structure's name (the table's key)."""

ARRAY_SECTIONS = ("static_obstacles", "planners")
"""Array-of-tables sections: one README row whose meaning names every key."""

COMPUTED = {
    ("", "name"): "file stem",
    ("obstacles.rvo", "wall_time_horizon"): "dt",
    ("task", "candidates"): "`{4, 25, 46}^2` (3D: z = 10)",
    ("sensor", "rays"): "from `resolution_deg`",
    ("task", "start_yaw_deg"): '`"goal"`',
    ("obstacles", "structure"): "none",
    ("obstacles", "maps"): "none",
    ("task", "pairs_flown"): "all",
    ("obstacles.structures.name", "headings"): "the scenario's",
    ("obstacles.structures.name", "motion"): "the scenario's",
}
"""Defaults computed at parse time (the field's default is a sentinel): README text expected for each."""


def _readme_rows() -> dict[tuple[str, str], str]:
    """(section, key) -> default cell of the docs/scenarios.md "Scenario reference" table (array sections: meaning cell)."""
    text = (ROOT / "docs" / "scenarios.md").read_text(encoding="utf-8")
    m = re.search(r"^## Scenario reference\n(.*?)(?=^## )", text, re.S | re.M)
    assert m, 'README.md has no "## Scenario reference" section'
    rows, section = {}, ""
    for line in m.group(1).splitlines():
        if not line.startswith("|") or line.startswith(("| field", "|---")):
            continue
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        key, default, meaning = cells[0], cells[1], cells[2]
        head = re.fullmatch(r"\*\*\[\[?([a-z_.]+)\]\]?\*\*", key)
        if head:
            section = head.group(1)
            if section in ARRAY_SECTIONS:
                rows[(section, "*")] = f"{default} | {meaning}"
            continue
        if re.fullmatch(r"`\[[a-z_.]+\]`", key):          # a sub-table row such as `[obstacles.rvo]`
            continue
        names = re.findall(r"`([a-z0-9_.]+)`", key)
        values = re.findall(r"`[^`]*`", default) if len(names) > 1 else [default]
        assert len(values) == len(names), f"README row {line!r}: one default per field"
        for name, value in zip(names, values):
            sec = section
            if "." in name:                                   # rvo.time_horizon -> section obstacles.rvo
                sub, name = name.rsplit(".", 1)
                sec = f"{section}.{sub}"
            rows[(sec, name)] = value
    return rows


def _literal(text: str):
    """A TOML literal written in the README (backticks removed), lists as tuples."""
    v = tomllib.loads(f"v = {text}")["v"]
    return tuple(v) if isinstance(v, list) else v


def _as_grid(v):
    return v if isinstance(v, tuple) else (v,)


def _split(cell: str) -> tuple[str, str | None]:
    """'`1.0` (3D `2.0`)' -> ('1.0', '2.0'); '`60` (3D only)' -> ('60', 'only'); '`2`' -> ('2', None)."""
    m = re.fullmatch(r"`([^`]+)`(?: \(3D (?:`([^`]+)`|(only))\))?", cell)
    assert m, f"unreadable default {cell!r}"
    return m.group(1), m.group(2) or m.group(3)


def _keys(section: str) -> list[str]:
    cls = SECTIONS[section]
    return [f.name for f in dataclasses.fields(cls) if (section, f.name) not in NOT_KEYS]


def _resolved(section: str, dims: int):
    sc = C.parse_scenario({"world": {"dims": dims}} if dims == 3 else {})
    obj = sc
    for part in ("planners" if section == "planners" else section).split("."):
        if part:
            obj = getattr(obj, part)
    return obj[0] if section == "planners" else obj


ROWS = _readme_rows()


def test_readme_table_lists_every_scenario_key():
    for section in SECTIONS:
        if section in ARRAY_SECTIONS:
            row = ROWS.get((section, "*"))
            assert row, f"README table: no **[[{section}]]** row"
            missing = [k for k in _keys(section) if not re.search(rf"`{k}\b", row)]
            assert not missing, f"README **[[{section}]]** row does not name {missing}"
            continue
        missing = [k for k in _keys(section) if (section, k) not in ROWS]
        assert not missing, f"README table [{section or 'top level'}] lacks rows for {missing}"
    extra = [k for k in ROWS if k[1] != "*" and (k[0] not in SECTIONS or k[1] not in _keys(k[0]))]
    assert not extra, f"README table rows with no dataclass field: {extra}"


THREE_D = {("world", "size"): C.WorldConfig.SIZE_3D,
           ("sensor", "resolution_deg"): C.SensorConfig.RESOLUTION_3D_DEG,
           ("sensor", "vfov_deg"): C.SensorConfig.VFOV_3D_DEG,
           ("obstacles.rvo", "n_headings"): RVOParams.N_HEADINGS_3D}
"""Defaults that differ in 3D (docs/scenarios.md "Scenario reference" (3D ...)): ClassVars of the dataclass."""

BY_DIMS = {("obstacles.rvo", "n_headings"): RVOParams.N_HEADINGS_2D, ("sensor", "vfov_deg"): None}
"""Fields whose default is None, resolved per dims: the 2D value (None: 3D only)."""

GRIDS = {("obstacles", "count"), ("obstacles", "radius"), ("obstacles", "speed"), ("drone", "v_max")}
"""Grid fields: a README scalar is a one-value grid."""


@pytest.mark.parametrize("key", sorted(k for k in ROWS if k[1] != "*"), ids=lambda k: ".".join(filter(None, k)))
def test_readme_default_matches_the_dataclass(key):
    section, name = key
    cell = ROWS[key]
    cls = SECTIONS[section]
    fd = _defaults(cls).get(name, dataclasses.MISSING)
    where = f"README default of {'.'.join(filter(None, key))} ({cls.__name__}.{name} = {fd!r})"
    if key in COMPUTED:
        assert cell == COMPUTED[key], f"{where}: {cell!r}, expected {COMPUTED[key]!r}"
        assert fd in (dataclasses.MISSING, None, ()), f"{where}: the field has a default now; document it"
        return
    main, alt = _split(cell)
    assert fd is not dataclasses.MISSING, f"{where}: the field has no default"
    if key in BY_DIMS:
        assert fd is None, f"{where}: expected None (resolved per dims)"
        two = BY_DIMS[key]
    else:
        two = fd
    three = THREE_D.get(key, two)
    lit = (lambda t: _as_grid(_literal(t))) if key in GRIDS else _literal
    if alt == "only":
        assert two is None and lit(main) == three, f"{where}: README says {cell!r}, 3D default {three!r}"
    else:
        assert lit(main) == two, f"{where}: README says {main!r}, the 2D default is {two!r}"
        assert (lit(alt) if alt else two) == three, f"{where}: README says {cell!r}, the 3D default is {three!r}"
    if section == "obstacles.structures.name":      # an empty scenario has no structure: parse one of its own
        st = C.parse_scenario({"obstacles": {"structure": "own", "structures": {"own": {}}}}).obstacles.structures[0]
        assert getattr(st, name) == two, f"{where}: an empty structure resolves to {getattr(st, name)!r}"
        return
    if key != ("world", "dims") and (key not in BY_DIMS or two is None):   # what an empty scenario resolves to
        d2, d3 = getattr(_resolved(section, 2), name), getattr(_resolved(section, 3), name)
        assert (d2, d3) == (two, three), f"{where}: an empty scenario resolves to {d2!r} (2D), {d3!r} (3D)"


def test_array_section_defaults():
    assert ROWS[("static_obstacles", "*")].startswith("none |") and C.parse_scenario({}).static_obstacles == ()
    d = _defaults(C.PlannerEntry)
    assert ROWS[("planners", "*")].startswith(f"one entry: `{d['trajectory']}` + `{d['gaze']}` |")
    assert C.parse_scenario({}).planners == (C.PlannerEntry(),)
    assert f'`kind = "{C.StaticObstacleConfig.DEFAULT_KIND}"`' in ROWS[("static_obstacles", "*")]


def test_parsers_write_no_default_of_their_own():
    """The validators' default argument is never a literal in pbdyn/config/parser.py: it comes from the dataclasses."""
    tree = ast.parse((ROOT / "pbdyn" / "config" / "parser.py").read_text(encoding="utf-8"))
    bad = []
    for node in ast.walk(tree):
        if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
                and node.func.id in ("_number", "_integer", "_string") and len(node.args) >= 4):
            continue
        arg = node.args[3]
        if isinstance(arg, (ast.List, ast.Tuple)) or isinstance(arg, ast.Constant) and arg.value is not None:
            bad.append(f"pbdyn/config/parser.py:{node.lineno}: {ast.unparse(node)}")
    assert not bad, "literal defaults in the parsers (use the dataclass field's default):\n" + "\n".join(bad)
