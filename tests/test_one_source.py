"""One source of truth for metric and outcome names: pbdyn.metrics.catalog and pbdyn.outcome.

The catalog must agree with the registry's functions, and no other module of pbdyn/ or tools/ may write a literal
list of two or more metric names or outcome names (derive it from the table / the enum instead).
"""

from __future__ import annotations

import ast
import inspect
from pathlib import Path

from pbdyn.analysis import report, success
from pbdyn.experiments import tasks
from pbdyn.metrics import cached, catalog
from pbdyn.metrics.registry import METRICS
from pbdyn.outcome import FAILURES, OUTCOMES, Outcome

ROOT = Path(__file__).resolve().parents[1]

OWNERS = {"metric": "pbdyn/metrics/catalog.py", "outcome": "pbdyn/outcome.py"}
ALLOWED = {("tools/bench/bench_metrics.py", "PROGRAM")}
"""(file, assigned name) of literals allowed to hold several names: measured data keyed by metric, not a list."""


def test_catalog_drives_the_registry():
    assert tuple(METRICS) == catalog.NAMES
    for m in catalog.METRIC_TABLE:
        fn = METRICS[m.name]
        assert fn.__module__ == m.module and fn.__name__ == m.name, m.name
        params = inspect.signature(fn).parameters
        assert ("backend" in params) == m.backend, f"{m.name}: backend flag vs signature"
        assert m.direction in (catalog.HARDER, catalog.EASIER) and m.unit and m.label and m.equation
        if m.dense:
            assert catalog.INFO[m.dense].sparse == m.name and m.sparse is None
        if m.sparse:
            assert catalog.INFO[m.sparse].dense == m.name and m.dense is None
    rows = sorted(m.table_row for m in catalog.METRIC_TABLE if m.table_row is not None)
    assert rows == list(range(1, len(rows) + 1))


def test_derived_lists_are_unchanged():
    """The lists each consumer wrote before the catalog existed (their order is behaviour: output order)."""
    assert cached.SPARSE == ("density", "traversability", "dynamic_traversability", "vo_feasibility",
                             "survivability", "global_survivability", "flux", "static_share")
    assert tasks.METRIC_SET == ("density", "traversability", "dynamic_traversability", "vo_feasibility",
                                "vo_feasibility_dense", "survivability", "survivability_dense",
                                "global_survivability", "flux", "static_share")
    assert report.METRIC_ORDER == ("density", "traversability", "dynamic_traversability", "survivability",
                                   "survivability_dense", "global_survivability", "vo_feasibility",
                                   "vo_feasibility_dense")
    assert report.BAND_METRICS == ("survivability", "survivability_dense")
    assert cached.BACKEND_METRICS == ("survivability", "survivability_dense", "global_survivability")
    assert success.OUTCOMES == OUTCOMES == ("success", "static_collision", "dynamic_collision", "freezing",
                                            "deadlock", "invalid_plan", "error")
    assert set(FAILURES) == set(Outcome) - {Outcome.SUCCESS, Outcome.ERROR}


def _literals(tree: ast.AST):
    """(assigned name or "", container node) for every tuple/list/set literal and dict (its keys)."""
    named = {}
    for node in ast.walk(tree):
        if isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            for t in targets:
                if isinstance(t, ast.Name):
                    named[id(node.value)] = t.id
    for node in ast.walk(tree):
        if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
            yield named.get(id(node), ""), node, node.elts
        elif isinstance(node, ast.Dict):
            yield named.get(id(node), ""), node, [k for k in node.keys if k is not None]


def test_no_other_module_lists_metric_or_outcome_names():
    vocab = {"metric": set(catalog.NAMES), "outcome": set(OUTCOMES)}
    found = []
    for path in sorted((ROOT / "pbdyn").rglob("*.py")) + sorted((ROOT / "tools").rglob("*.py")):
        rel = path.relative_to(ROOT).as_posix()
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for name, node, elts in _literals(tree):
            strings = {e.value for e in elts if isinstance(e, ast.Constant) and isinstance(e.value, str)}
            for kind, names in vocab.items():
                hits = strings & names
                if len(hits) >= 2 and rel != OWNERS[kind] and (rel, name) not in ALLOWED:
                    found.append(f"{rel}:{node.lineno}: {kind} names {sorted(hits)} written out; derive them from "
                                 f"{OWNERS[kind]}")
    assert not found, "\n".join(found)
