"""The README stays true: the paths it names exist, and its Python examples run.

Paths. A path the README mentions (in prose, in a code span, in a code block or as a link target) must exist in
the repository when it is
  - a token starting with a source folder, ``pbdyn/``, ``scenarios/``, ``tests/``, ``tools/``, ``urdf/`` (or
    ``docs/``, ``examples/``, which the repository does not have, so that a mention of them is caught);
  - a bundled scenario's name, ``datasets/NAME`` or ``worlds/NAME`` (then ``scenarios/NAME.toml`` must exist);
  - a file name ending in ``.md`` or ``.cff``, or ``LICENSE`` / ``Makefile`` (at the repository root);
  - a relative link target ``[text](target)``.
Not checked: output paths (anything under ``results/`` or ``out/``, and names ending in ``.sqlite``, ``.npz``,
``.csv``, ``.parquet``, ``.gif``, ``.png``, ``.txt`` or naming a ``figures`` folder) and placeholders (a token
holding ``<``, ``*``, ``{`` or ``...``).

Examples. Every fenced block tagged exactly ```python runs, in README order, in one namespace: a fresh module
registered in sys.modules (like a notebook's), from an empty temporary working directory, with the repository
root importable (the examples import ``tools.templates``) and the rollout cache of tests/conftest.py. A block that
must not run here (a cluster recipe, anything slow or needing a service) is tagged ```python-norun; any other tag
starting with "py" is an error, so a typo cannot silently skip an example. Keep the examples fast (< 30 s in all).
"""

from __future__ import annotations

import re
import sys
import types
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")

SOURCE_DIRS = ("pbdyn", "scenarios", "tests", "tools", "urdf", "docs", "examples")
OUTPUT_SUFFIXES = (".sqlite", ".npz", ".csv", ".parquet", ".gif", ".png", ".txt")
PLACEHOLDER = re.compile(r"[<*{]|\.\.\.")
FENCE = re.compile(r"^```([^\n`]*)\n(.*?)^```[ \t]*$", re.S | re.M)
RUN_TAG, NORUN_TAG = "python", "python-norun"


def _is_output(path: str) -> bool:
    return (path.startswith(("results/", "out/")) or path.endswith(OUTPUT_SUFFIXES)
            or "figures" in path.split("/"))


def readme_paths() -> dict[str, str]:
    """Every checked path the README mentions -> the repository path that must exist (see the module docstring)."""
    found: dict[str, str] = {}
    folders = "|".join(SOURCE_DIRS)
    for m in re.finditer(rf"(?<![\w.$~/-])((?:{folders})/[\w./<>*{{}}-]*)", README):
        path = m.group(1).rstrip(".")
        found[path] = path
    for m in re.finditer(r"(?<![\w./-])((?:datasets|worlds)/[\w<>*{}.-]+)", README):
        name = m.group(1).rstrip(".")
        if name.endswith(".toml"):
            continue                       # a file path: covered as scenarios/... when written out
        found[name] = f"scenarios/{name}.toml"
    for m in re.finditer(r"(?<![\w/.-])([\w-]+\.(?:md|cff)|LICENSE|Makefile)\b", README):
        found[m.group(1)] = m.group(1)
    for m in re.finditer(r"\]\(([^)\s]+)\)", README):
        target = m.group(1)
        if not re.match(r"[a-z]+:|#", target):
            found[target] = target.split("#")[0]
    return {k: v for k, v in found.items() if not _is_output(k) and not PLACEHOLDER.search(k)}


def python_blocks() -> list[tuple[int, str]]:
    """(line number, code) of every ```python block, in README order."""
    blocks = []
    for m in FENCE.finditer(README):
        tag = m.group(1).strip()
        if tag == RUN_TAG:
            blocks.append((README.count("\n", 0, m.start()) + 2, m.group(2)))
    return blocks


def test_readme_mentions_only_existing_paths():
    paths = readme_paths()
    assert "tools/templates/my_planner.py" in paths and "CITATION.cff" in paths     # the rule sees the README
    missing = sorted(f"{k} -> {v}" for k, v in paths.items() if not (ROOT / v).exists())
    assert not missing, f"README.md names paths that are not in the repository: {missing}"


def test_readme_code_fences_are_tagged_known_ways():
    tags = [m.group(1).strip() for m in FENCE.finditer(README)]
    bad = [t for t in tags if t.startswith("py") and t not in (RUN_TAG, NORUN_TAG)]
    assert not bad, f"unknown Python fence tags {bad}: use ```{RUN_TAG} (executed) or ```{NORUN_TAG}"
    assert tags.count(RUN_TAG) >= 5


def test_readme_python_examples_run(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(ROOT))
    module = types.ModuleType("readme_examples")
    monkeypatch.setitem(sys.modules, module.__name__, module)
    for line, code in python_blocks():
        try:
            exec(compile(code, f"README.md (block at line {line})", "exec"), module.__dict__)
        except Exception as exc:
            pytest.fail(f"the README's Python block at line {line} raised {type(exc).__name__}: {exc}")

    ns = module.__dict__
    from pbdyn.sim.outcome import OUTCOMES

    assert ns["result"].outcome in OUTCOMES
    assert ns["metrics"]["survivability"]["n_samples"] > 0
    trials = ns["trials"]
    assert len(trials) == 6 and {"metric_survivability", "start_x", "goal_x"} <= set(trials.columns)
    assert (tmp_path / "results" / "mine.sqlite").is_file() and (tmp_path / "trials.csv").is_file()
    out = capsys.readouterr().out
    assert "start - start: must be a sequence of numbers" in out                    # the ConfigError example
    assert "plan contract respected" in out and "plan broke speed at sample" in out   # check_planner's reports
    assert not ns["report"].ok and "invalid_plan" in ns["report"].outcomes       # the last report: TooFast
