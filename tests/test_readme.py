"""The README stays true: the paths it names exist, and its Python examples run.

The same rules hold for every page of docs/ (tests/test_docs.py uses the helpers of this module), so a page is
checked exactly as the README is.

Paths. A path a page mentions (in prose, in a code span, in a code block or as a link target) must exist in
the repository when it is
  - a token starting with a source folder, ``pbdyn/``, ``scenarios/``, ``tests/``, ``tools/``, ``urdf/``, ``docs/``
    (or ``examples/``, which the repository does not have, so that a mention of it is caught), read from the
    repository root;
  - a bundled scenario's name, ``datasets/NAME`` or ``worlds/NAME`` (then ``scenarios/NAME.toml`` must exist);
  - a file name ending in ``.md`` or ``.cff``, or ``LICENSE`` / ``Makefile``: in the page's folder or at the
    repository root;
  - a relative link target ``[text](target)``, read from the page's folder.
Not checked: output paths (anything under ``results/`` or ``out/``, names ending in ``.sqlite``, ``.npz``,
``.csv``, ``.parquet``, ``.gif``, ``.png``, ``.txt`` or naming a ``figures`` folder, and the pages `pbdyn bench`
writes, ``card.md`` and ``compare.md``) and placeholders (a token
holding ``<``, ``*``, ``{`` or ``...``). Links and images are checked once more, without those exceptions, by
tests/test_docs.py, which also checks their ``#anchors``.

Examples. Every fenced block tagged exactly ```python runs, in page order, in one namespace per page: a fresh
module registered as ``__main__`` (like a notebook's or a script's, so a ``if __name__ == "__main__":`` block runs
and the batch's spawned workers have no file to import again), from an empty temporary working directory, with the
repository root importable (the examples import ``tools.templates``) and the rollout cache of tests/conftest.py. A
block that must not run here (a cluster recipe, anything slow or needing a service) is tagged ```python-norun; any
other tag starting with "py" is an error, so a typo cannot silently skip an example. Keep the examples of all
pages together fast (< 60 s).
"""

from __future__ import annotations

import re
import sys
import types
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README_PATH = ROOT / "README.md"
README = README_PATH.read_text(encoding="utf-8")

SOURCE_DIRS = ("pbdyn", "scenarios", "tests", "tools", "urdf", "docs", "examples")
OUTPUT_SUFFIXES = (".sqlite", ".npz", ".csv", ".parquet", ".gif", ".png", ".txt")
OUTPUT_NAMES = ("card.md", "compare.md")
"""Files a command writes (the score card's and the comparison's pages of `pbdyn bench`)."""
PLACEHOLDER = re.compile(r"[<*{]|\.\.\.")
ENV_ID = re.compile(r"^pbdyn/[A-Z]\w*-v\d+$")
"""A Gymnasium environment id (pbdyn/Avoid2D-v0), not a path."""
FENCE = re.compile(r"^```([^\n`]*)\n(.*?)^```[ \t]*$", re.S | re.M)
LINK = re.compile(r"\]\(([^)\s]+)\)")
RUN_TAG, NORUN_TAG = "python", "python-norun"


def _is_output(path: str) -> bool:
    return (path.startswith(("results/", "out/")) or path.endswith(OUTPUT_SUFFIXES) or path in OUTPUT_NAMES
            or "figures" in path.split("/"))


def _rel(path: Path) -> str:
    return path.resolve().relative_to(ROOT).as_posix()


def page_paths(text: str, page: Path) -> dict[str, tuple[str, ...]]:
    """Every checked path ``page`` mentions -> the repository paths of which one must exist (module docstring)."""
    found: dict[str, tuple[str, ...]] = {}
    here = page.parent
    folders = "|".join(SOURCE_DIRS)
    for m in re.finditer(rf"(?<![\w.$~/-])((?:{folders})/[\w./<>*{{}}-]*)", text):
        path = m.group(1).rstrip(".")
        found[path] = (path,)
    for m in re.finditer(r"(?<![\w./-])((?:datasets|worlds)/[\w<>*{}./-]+)", text):
        name = m.group(1).rstrip("./")
        if name.endswith(".toml"):
            continue                       # a file path: covered as scenarios/... when written out
        found[name] = (f"scenarios/{name}.toml",)
    for m in re.finditer(r"(?<![\w/.-])([\w-]+\.(?:md|cff)|LICENSE|Makefile)\b", text):
        name = m.group(1)
        found[name] = tuple(dict.fromkeys((_rel(here / name), name)))
    for m in LINK.finditer(text):
        target = m.group(1)
        if not re.match(r"[a-z]+:|#", target):
            found[target] = (_rel(here / target.split("#")[0]),)
    return {k: v for k, v in found.items() if not _is_output(k) and not PLACEHOLDER.search(k) and not ENV_ID.match(k)}


def missing_paths(page: Path) -> list[str]:
    paths = page_paths(page.read_text(encoding="utf-8"), page)
    return sorted(f"{k} -> {' or '.join(v)}" for k, v in paths.items() if not any((ROOT / p).exists() for p in v))


def fence_tags(text: str) -> list[str]:
    return [m.group(1).strip() for m in FENCE.finditer(text)]


def bad_fence_tags(text: str) -> list[str]:
    return [t for t in fence_tags(text) if t.startswith("py") and t not in (RUN_TAG, NORUN_TAG)]


def python_blocks(text: str = README) -> list[tuple[int, str]]:
    """(line number, code) of every ```python block of ``text``, in page order."""
    blocks = []
    for m in FENCE.finditer(text):
        if m.group(1).strip() == RUN_TAG:
            blocks.append((text.count("\n", 0, m.start()) + 2, m.group(2)))
    return blocks


def run_examples(page: Path, tmp_path: Path, monkeypatch) -> dict:
    """Run every ```python block of ``page`` as the module docstring says; returns the namespace."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(ROOT))
    module = types.ModuleType("__main__")
    monkeypatch.setitem(sys.modules, "__main__", module)
    name = _rel(page)
    for line, code in python_blocks(page.read_text(encoding="utf-8")):
        try:
            exec(compile(code, f"{name} (block at line {line})", "exec"), module.__dict__)
        except Exception as exc:
            pytest.fail(f"the Python block of {name} at line {line} raised {type(exc).__name__}: {exc}")
    return module.__dict__


def test_readme_mentions_only_existing_paths():
    paths = page_paths(README, README_PATH)
    assert "tools/templates/my_planner.py" in paths and "CITATION.cff" in paths     # the rule sees the README
    assert "docs/README.md" in paths                                                 # and links the docs' index
    missing = missing_paths(README_PATH)
    assert not missing, f"README.md names paths that are not in the repository: {missing}"


def test_readme_code_fences_are_tagged_known_ways():
    bad = bad_fence_tags(README)
    assert not bad, f"unknown Python fence tags {bad}: use ```{RUN_TAG} (executed) or ```{NORUN_TAG}"
    assert fence_tags(README).count(RUN_TAG) >= 1


def test_readme_stays_a_first_visit():
    """The README is the short tour; the reference lives in docs/ (one topic per page)."""
    assert README.count("\n") <= 300
    for heading in ("## Install and the two commands", "## Workflow 1: benchmark your planner",
                    "## Workflow 2: the difficulty of your world", "## Workflow 3: learn a policy",
                    "## Headline results", "## License and citation"):
        assert f"\n{heading}\n" in README, heading


def test_readme_python_examples_run(tmp_path, monkeypatch, capsys):
    ns = run_examples(README_PATH, tmp_path, monkeypatch)
    from pbdyn.outcome import OUTCOMES

    assert ns["result"].outcome in OUTCOMES
    out = capsys.readouterr().out
    assert out.split()[0] in OUTCOMES
