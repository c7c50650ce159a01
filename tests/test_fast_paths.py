"""The list of fast paths and their reference twins (docs/architecture.md "Fast paths and their reference twins")
cannot go stale: every function or class it names exists (importable by its dotted path), every test it names is
in tests/, every twin defined in pbdyn or the tests follows the naming convention, and every twin named by the
convention in pbdyn or the tests is listed."""

from __future__ import annotations

import ast
import importlib
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "architecture.md"
HEADING = "## Fast paths and their reference twins"
COLUMNS = ["fast path", "reference twin", "compared by", "same"]
DOTTED = re.compile(r"^[A-Za-z_]\w*(?:\.[A-Za-z_]\w*)+$")
TEST_ID = re.compile(r"^(tests/[\w/]+\.py)::(\w+(?:::\w+)*)$")
SUFFIXES = ("_reference", "Reference")
OWN_JOB = "own job"
"""A twin cell holding these words names a production path in its own right (it keeps its name)."""
NOT_RENAMED = "not renamed"
"""A twin in pbdyn/sim/ or pbdyn/world/ whose cell holds these words is listed but not yet named by the convention."""
UNRENAMED_PACKAGES = ("pbdyn.sim.", "pbdyn.world.")


def table() -> list[dict[str, str]]:
    """The rows of the page's table (column name -> cell text)."""
    lines = PAGE.read_text(encoding="utf-8").splitlines()
    start = lines.index(HEADING)
    rows = []
    for line in lines[start + 1:]:
        if line.startswith("## "):
            break
        if line.startswith("|"):
            rows.append([c.strip() for c in line.strip().strip("|").split("|")])
        elif rows:
            break
    assert rows and [c.lower() for c in rows[0]] == COLUMNS, rows[:1]
    assert set(rows[1][0]) <= set("-: "), "the header's separator row"
    body = [dict(zip(COLUMNS, r)) for r in rows[2:]]
    assert all(len(r) == len(COLUMNS) for r in rows[2:]), "a row with another number of cells"
    return body


def spans(cell: str) -> list[str]:
    """The texts of the code spans (`...`) of a cell."""
    return re.findall(r"`([^`]+)`", cell)


def dotted_names(cell: str) -> list[str]:
    """The code spans of a cell that are dotted paths (module.attribute...)."""
    return [s for s in spans(cell) if DOTTED.match(s)]


def resolve(name: str):
    """The object a dotted path names: the longest importable module prefix, then attributes."""
    parts = name.split(".")
    for k in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:k]))
        except ModuleNotFoundError:
            continue
        for attr in parts[k:]:
            obj = getattr(obj, attr)
        return obj
    raise ModuleNotFoundError(name)


def named_tests(cell: str) -> list[tuple[str, str]]:
    """(file, test name) of the code spans of a cell written tests/FILE.py::test_name."""
    return [m.groups() for m in (TEST_ID.match(s) for s in spans(cell)) if m]


ROWS = table()


def _row_id(row: dict) -> str:
    """A row's name in test ids: its fast path."""
    names = dotted_names(row["fast path"])
    return names[0] if names else row["fast path"][:40]


@pytest.mark.parametrize("row", ROWS, ids=[_row_id(r) for r in ROWS])
def test_every_named_function_class_and_test_exists(row):
    """Both implementations resolve by their dotted paths, the comparing tests exist, "same" is stated."""
    for column in ("fast path", "reference twin"):
        names = dotted_names(row[column])
        assert names, f"{column} of {_row_id(row)!r} names no dotted path in backticks"
        for name in names:
            try:
                resolve(name)
            except (ImportError, AttributeError) as exc:
                pytest.fail(f"{column} {name!r} does not exist ({type(exc).__name__}: {exc})")
    tests = named_tests(row["compared by"])
    assert tests, f"{_row_id(row)!r} names no test as tests/FILE.py::test_name"
    for path, qualname in tests:
        file = ROOT / path
        assert file.is_file(), path
        scope = ast.parse(file.read_text(encoding="utf-8")).body
        for part in qualname.split("::"):
            found = [n for n in scope if isinstance(n, (ast.FunctionDef, ast.ClassDef)) and n.name == part]
            assert found, f"{path}::{qualname} does not exist"
            scope = found[0].body
    assert row["same"].startswith(("bit-identical", "tolerance")), row["same"]


@pytest.mark.parametrize("row", ROWS, ids=[_row_id(r) for r in ROWS])
def test_the_twins_follow_the_naming_convention(row):
    """A twin defined in pbdyn or the tests ends in _reference (a class: Reference), unless it does a job of its own;
    twins in pbdyn/sim/ and pbdyn/world/ may still be marked not renamed."""
    cell = row["reference twin"]
    for name in dotted_names(cell):
        if not name.startswith(("pbdyn.", "tests.")) or name.endswith(SUFFIXES) or OWN_JOB in cell:
            continue
        assert name.startswith(UNRENAMED_PACKAGES) and NOT_RENAMED in cell, \
            f"reference twin {name!r} is not named <...>{SUFFIXES[0]} (nor marked '{OWN_JOB}')"


def _defined_twins(path: Path, module: str) -> list[str]:
    """Dotted names of the functions, methods and classes of ``path`` named by the convention (test functions and
    fixtures aside)."""
    out = []

    def visit(nodes, prefix):
        for n in nodes:
            if isinstance(n, ast.ClassDef):
                if n.name.endswith(SUFFIXES[1]):
                    out.append(f"{prefix}.{n.name}")
                visit(n.body, f"{prefix}.{n.name}")
            elif isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)) and n.name.endswith(SUFFIXES[0]):
                fixture = any("fixture" in ast.unparse(d) for d in n.decorator_list)
                if not n.name.startswith("test_") and not fixture:
                    out.append(f"{prefix}.{n.name}")

    visit(ast.parse(path.read_text(encoding="utf-8")).body, module)
    return out


def test_every_twin_named_by_the_convention_is_listed():
    listed = {name for row in ROWS for name in dotted_names(row["reference twin"])}
    found = []
    for folder in ("pbdyn", "tests"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            module = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            found += _defined_twins(path, module)
    missing = sorted(set(found) - listed)
    assert not missing, f"reference twins missing from docs/architecture.md's table: {missing}"
