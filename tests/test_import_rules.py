"""The one-way data flow (docs/design.md "The data flow (one direction)", "Package sketch") as import rules.

RULES says which pbdyn sub-packages (or top-level modules) each one may import; a unit may always import itself.
Every import in every pbdyn module is checked with ``ast`` - module level, inside functions (lazy imports),
under ``if TYPE_CHECKING`` and ``importlib.import_module("pbdyn....")`` with a literal name.

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


def imports_of(source: str, module: str, is_package: bool = False):
    """(line, imported module text, unit) for every pbdyn import in ``source`` (module: its dotted name)."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            for a in node.names:
                unit = _unit_of_module(a.name)
                if unit:
                    out.append((node.lineno, a.name, unit))
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:                                    # relative: resolve against this module's package
                pkg = module.split(".") if is_package else module.split(".")[:-1]
                pkg = pkg[:len(pkg) - node.level + 1]
                base = ".".join(pkg + ([base] if base else []))
            if base == "pbdyn":                               # from pbdyn import x
                for a in node.names:
                    if _is_submodule(a.name):
                        out.append((node.lineno, f"pbdyn.{a.name}", a.name))
                    elif a.name not in ROOT_METADATA:
                        out.append((node.lineno, f"pbdyn (name {a.name!r})", "pbdyn"))
            else:
                unit = _unit_of_module(base)
                if unit:
                    out.append((node.lineno, base, unit))
        elif (isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant)
              and isinstance(node.args[0].value, str)
              and (getattr(node.func, "attr", None) == "import_module"
                   or getattr(node.func, "id", None) in ("import_module", "__import__"))):
            unit = _unit_of_module(node.args[0].value)
            if unit:
                out.append((node.lineno, node.args[0].value, unit))
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
