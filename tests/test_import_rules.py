"""The one-way data flow (docs/design.md "The data flow (one direction)", "Package sketch") as import rules.

Two rules, between folders and within them. (1) RULES says which pbdyn sub-packages (or top-level modules) each one
may import; a unit may always import itself, and any module may import the package root's __version__. (2) The
module import graph has no circle: pbdyn module -> the pbdyn modules it imports, so within a folder too the modules
form a one-way order (a lower module never imports a higher one). Every import in every pbdyn module is read with
``ast`` - module level, inside functions (lazy imports: a circle closed by one still counts), under
``if TYPE_CHECKING`` and ``importlib.import_module("pbdyn....")`` with a literal name. An import names a module
(``from pbdyn.world import maps``: pbdyn.world.maps; ``from pbdyn.config import Scenario``: pbdyn.config), not the
packages above it, whose __init__ may re-export their own modules.

Layers, bottom to top: usercode (running foreign code; imports nothing of pbdyn), errors, files (atomic writes),
codeid (code identity by content),
limits (resource limits), urdf (URDF validation), resources, jit (numba's njit, its cache never in the way), outcome
(how a trial ends: the vocabulary sim/ writes and analysis/ reads), motion (the obstacle motion models and their
registry: config validates their names and tables, world's rollouts run them), config | world | perception |
planning | metrics (beside perception and planning: it sees rollouts only) | sim, and analysis beside it (it reads
stored rows, never a trial) | experiments (evaluate feeds stored results to analysis) | benchmark (frozen suites flown
by the batch runner, score cards) | api (the one door) | cli, gym, __main__, and the package root pbdyn/__init__.py,
which re-exports the api. gym_ids (the Gymnasium ids) stands alone and imports nothing of pbdyn: the start-up hook
beside the package (pbdyn_gym_hook.py) reads it when Gymnasium is imported.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "pbdyn"

_BASE = ("usercode", "errors", "files", "codeid", "limits", "urdf", "resources", "jit", "outcome", "motion", "config")
_BELOW_SIM = _BASE + ("world", "perception", "planning", "metrics")
_BELOW_EXPERIMENTS = _BELOW_SIM + ("sim", "analysis")
_BELOW_API = _BELOW_EXPERIMENTS + ("experiments",)
RULES: dict[str, tuple[str, ...]] = {
    "usercode": (),
    "errors": ("usercode",),
    "files": ("usercode", "errors"),
    "codeid": ("usercode", "errors", "files"),
    "limits": ("usercode", "errors"),
    "urdf": ("usercode", "errors", "limits"),
    "resources": ("usercode", "errors"),
    "jit": (),
    "outcome": (),
    "motion": ("usercode", "errors", "limits"),
    "config": ("usercode", "errors", "files", "limits", "urdf", "resources", "motion"),
    "world": _BASE,
    "perception": _BASE + ("world",),
    "planning": _BASE + ("world", "perception"),
    "metrics": _BASE + ("world",),
    "sim": _BELOW_SIM,
    "analysis": _BASE + ("metrics",),
    "experiments": _BELOW_EXPERIMENTS,
    "benchmark": _BELOW_API,
    "api": _BELOW_API + ("benchmark",),
    "gym_ids": (),
    "gym": _BELOW_API + ("benchmark", "api", "gym_ids"),
    "cli": _BELOW_API + ("benchmark", "api"),
    "__main__": ("cli",),
    "pbdyn": _BELOW_API + ("benchmark", "api"),
}
"""unit -> units it may import. "pbdyn" is the package root: importing it, or a name it defines other than
__version__ (``from pbdyn import run``), is importing the public API."""

ROOT_METADATA = ("__version__",)
"""Names of the package root any module may import (they do not come from the api)."""

_TOP = ("api", "cli", "gym", "__main__", "pbdyn")


def _unit_of_file(path: Path) -> str:
    rel = path.relative_to(PACKAGE).with_suffix("").parts
    return "pbdyn" if rel == ("__init__",) else rel[0]


def _module_name(path: Path) -> str:
    parts = ("pbdyn",) + path.relative_to(PACKAGE).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _unit_of_module(dotted: str) -> str | None:
    """'pbdyn.world.maps' -> 'world'; 'pbdyn' -> 'pbdyn'; a non-pbdyn module -> None."""
    parts = dotted.split(".")
    if parts[0] != "pbdyn":
        return None
    return parts[1] if len(parts) > 1 else "pbdyn"


def _is_submodule(name: str) -> bool:
    return name in RULES or (PACKAGE / f"{name}.py").is_file() or (PACKAGE / name / "__init__.py").is_file()


def _imports(source: str, module: str, is_package: bool = False):
    """(line, absolute module, names) for every import in ``source`` (module: its dotted name); names are those of
    ``from module import names``, () for ``import module`` and ``import_module("module")``."""
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            for a in node.names:
                yield node.lineno, a.name, ()
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:                                    # relative: resolve against this module's package
                pkg = module.split(".") if is_package else module.split(".")[:-1]
                pkg = pkg[:len(pkg) - node.level + 1]
                base = ".".join(pkg + ([base] if base else []))
            yield node.lineno, base, tuple(a.name for a in node.names)
        elif (isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant)
              and isinstance(node.args[0].value, str)
              and (getattr(node.func, "attr", None) == "import_module"
                   or getattr(node.func, "id", None) in ("import_module", "__import__"))):
            yield node.lineno, node.args[0].value, ()


def imports_of(source: str, module: str, is_package: bool = False):
    """(line, imported module text, unit) for every pbdyn import in ``source`` (module: its dotted name)."""
    out = []
    for line, base, names in _imports(source, module, is_package):
        if base == "pbdyn" and names:                         # from pbdyn import x
            for name in names:
                if _is_submodule(name):
                    out.append((line, f"pbdyn.{name}", name))
                elif name not in ROOT_METADATA:
                    out.append((line, f"pbdyn (name {name!r})", "pbdyn"))
            continue
        unit = _unit_of_module(base)
        if unit:
            out.append((line, base, unit))
    return out


def violations(path: Path, source: str | None = None) -> list[str]:
    """Readable messages for every import of ``path`` that RULES forbids."""
    unit = _unit_of_file(path)
    rel = path.relative_to(ROOT).as_posix()
    if unit not in RULES:
        return [f"{rel}: sub-package {unit!r} has no row in RULES (tests/test_import_rules.py): add one listing "
                f"what it may import"]
    allowed = set(RULES[unit]) | {unit}
    text = path.read_text(encoding="utf-8") if source is None else source
    out = []
    for line, what, target in imports_of(text, _module_name(path), path.name == "__init__.py"):
        if target in allowed:
            continue
        if target not in RULES:
            why = f"{target!r} is not a known pbdyn unit"
        else:
            why = f"{unit} may import only: {', '.join(sorted(RULES[unit])) or 'nothing of pbdyn'}"
        out.append(f"{rel}:{line}: imports {what} - {why}. The data flows one way (docs/design.md); move the shared "
                   f"code down to a unit both may import, or pass it in as an argument.")
    return out


MODULES = sorted(PACKAGE.rglob("*.py"))
MODULE_NAMES = {_module_name(p): p for p in MODULES}
"""Dotted name -> file of every pbdyn module."""


def test_every_pbdyn_import_follows_the_rules():
    found = [msg for path in MODULES for msg in violations(path)]
    assert not found, f"{len(found)} forbidden import(s):\n" + "\n".join(found)


def test_the_rules_are_a_one_way_order():
    """No cycles; nothing below the api may import api, cli, gym, __main__ or the package root; config and
    errors sit at the bottom, on usercode (stdlib only); config reads only the base modules and the motion models."""
    for unit, allowed in RULES.items():
        if unit not in _TOP:
            assert not set(allowed) & set(_TOP), f"{unit} may import {sorted(set(allowed) & set(_TOP))}"
    assert set(RULES["config"]) <= {"usercode", "errors", "files", "limits", "urdf", "resources", "motion"}
    assert RULES["errors"] == ("usercode",) and RULES["usercode"] == ()
    done: set[str] = set()

    def visit(u: str, stack: tuple[str, ...]) -> None:
        assert u not in stack, f"import rules have a cycle: {' -> '.join(stack + (u,))}"
        if u in done:
            return
        for v in RULES.get(u, ()):
            visit(v, stack + (u,))
        done.add(u)

    for u in RULES:
        visit(u, ())


def module_edges(source: str, module: str, is_package: bool = False, known=None) -> dict[str, int]:
    """pbdyn module -> line of its first import in ``source`` (module: its dotted name; known: the pbdyn module
    names, default every module of the package): the module named, or the module a ``from`` import takes a
    submodule of; the root's __version__ is no edge."""
    known = MODULE_NAMES if known is None else known
    out: dict[str, int] = {}
    for line, base, names in _imports(source, module, is_package):
        targets = [f"{base}.{n}" if f"{base}.{n}" in known else base for n in names
                   if not (base == "pbdyn" and n in ROOT_METADATA)] if names else [base]
        for target in targets:
            if target in known and target != module:
                out.setdefault(target, line)
    return out


def module_graph() -> dict[str, dict[str, int]]:
    """Every pbdyn module -> {pbdyn module it imports: line of the first such import}."""
    return {name: module_edges(path.read_text(encoding="utf-8"), name, path.name == "__init__.py")
            for name, path in MODULE_NAMES.items()}


def cycles(graph: dict[str, dict[str, int]]) -> list[list[str]]:
    """One circle [a, b, ..., a] per group of modules that import each other (a strongly connected component of
    ``graph``): the shortest one through the group's first module; [] when the graph is one-way."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    groups = []

    def visit(v: str) -> None:                                # Tarjan's algorithm
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = {stack.pop()}
            while v not in group:
                group.add(stack.pop())
            if len(group) > 1:
                groups.append(group)

    for v in sorted(graph):
        if v not in index:
            visit(v)
    out = []
    for group in groups:
        start = min(group)
        came = {start: None}
        todo = [start]
        while came[start] is None:                            # breadth first, back to start
            v = todo.pop(0)
            for w in sorted(graph[v]):
                if w == start and came[start] is None:
                    came[start] = v
                elif w in group and w not in came:
                    came[w] = v
                    todo.append(w)
        path, v = [start], came[start]
        while v != start:
            path.append(v)
            v = came[v]
        out.append([start] + path[:0:-1] + [start])
    return sorted(out)


def _circle_text(circle: list[str], graph: dict[str, dict[str, int]]) -> str:
    """'a (pbdyn/a.py:3) -> b (pbdyn/b.py:7) -> a': each module with the line that imports the next."""
    parts = [f"{a} ({MODULE_NAMES[a].relative_to(ROOT).as_posix()}:{graph[a][b]})" if a in MODULE_NAMES
             else f"{a} (line {graph[a][b]})" for a, b in zip(circle, circle[1:])]
    return " -> ".join(parts + [circle[-1]])


def test_the_module_import_graph_has_no_circle():
    graph = module_graph()
    found = cycles(graph)
    assert not found, (f"{len(found)} import circle(s); move what both sides need into a module below both (a lazy "
                       "import inside a function closes a circle too):\n" + "\n".join(_circle_text(c, graph)
                                                                                     for c in found))


def test_the_circle_finder_reports_each_circle_once():
    graph = {"a": {"b": 1}, "b": {"c": 2, "a": 5}, "c": {"a": 3}, "d": {"a": 1, "e": 2}, "e": {"d": 4}, "f": {}}
    assert cycles(graph) == [["a", "b", "a"], ["d", "e", "d"]]
    assert cycles({"a": {"b": 1}, "b": {"c": 1}, "c": {}}) == []
    assert _circle_text(["d", "e", "d"], graph) == "d (line 2) -> e (line 4) -> d"
    assert cycles({"x": {"y": 1}, "y": {"z": 1}, "z": {"x": 1}}) == [["x", "y", "z", "x"]]


def test_the_graph_counts_lazy_and_type_checking_imports_and_names_submodules():
    src = ("from typing import TYPE_CHECKING\nfrom pbdyn import __version__\nif TYPE_CHECKING:\n"
           "    from pbdyn.experiments.runner import run_batch\ndef f():\n    from pbdyn.world import maps\n"
           "    import pbdyn.sim.trial\n    from pbdyn.config import Scenario\n    from . import store\n")
    assert module_edges(src, "pbdyn.experiments.plan") == {
        "pbdyn.experiments.runner": 4, "pbdyn.world.maps": 6, "pbdyn.sim.trial": 7, "pbdyn.config": 8,
        "pbdyn.experiments.store": 9}


@pytest.mark.parametrize("source, bad", [
    ("from pbdyn.planning.view import Tracks\n", "pbdyn.planning.view"),
    ("def f():\n    import pbdyn.sim.trial as t\n", "pbdyn.sim.trial"),
    ("def f():\n    from pbdyn import api\n", "pbdyn.api"),
    ("from pbdyn import run\n", "pbdyn (name 'run')"),
    ("import importlib\nimportlib.import_module('pbdyn.cli')\n", "pbdyn.cli"),
    ("from ..experiments import store\n", "pbdyn.experiments"),
])
def test_the_checker_finds_forbidden_imports(source, bad):
    msgs = violations(PACKAGE / "perception" / "tracker.py", source)
    assert len(msgs) == 1 and f"imports {bad} -" in msgs[0] and "perception may import only" in msgs[0]
    line = source.count("\n", 0, source.index("pbdyn" if "pbdyn" in source else "..")) + 1
    assert msgs[0].startswith(f"pbdyn/perception/tracker.py:{line}:")


def test_allowed_imports_pass():
    src = "from pbdyn import __version__\nfrom pbdyn.errors import ConfigError\nfrom .grid import OccupancyGrid\n"
    assert violations(PACKAGE / "perception" / "tracker.py", src) == []
