"""Every page of docs/ stays true, as the README does (tests/test_readme.py states the rules and holds the helpers):
the paths a page names exist, its code fences are tagged known ways, and its ```python examples run. Besides,
every relative link and image of the README and of docs/ resolves to a file, every ``#anchor`` to a heading of
the page it points at, the index docs/README.md lists every page, and docs/cli.md lists every option of every
command.

docs/benchmark.md's examples fly a benchmark suite; they run in tests/test_bench.py
(test_the_benchmark_page_examples_run), not here, so that they run once.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from tests.test_readme import (FENCE, LINK, NORUN_TAG, README_PATH, ROOT, RUN_TAG, bad_fence_tags, missing_paths,
                               python_blocks, run_examples)

DOCS = ROOT / "docs"
PAGES = sorted(DOCS.glob("*.md"))
RUN_ELSEWHERE = {"benchmark.md": "tests/test_bench.py"}
"""Pages whose examples another test module runs (and must keep running)."""
EXAMPLE_PAGES = [p for p in PAGES if p.name not in RUN_ELSEWHERE
                 and python_blocks(p.read_text(encoding="utf-8"))]


def _ids(pages):
    return [p.name for p in pages]


# ------------------------------------------------------------------------------------------------ the pages
@pytest.mark.parametrize("page", PAGES, ids=_ids(PAGES))
def test_page_mentions_only_existing_paths(page):
    missing = missing_paths(page)
    assert not missing, f"{page.name} names paths that are not in the repository: {missing}"


@pytest.mark.parametrize("page", PAGES, ids=_ids(PAGES))
def test_page_code_fences_are_tagged_known_ways(page):
    bad = bad_fence_tags(page.read_text(encoding="utf-8"))
    assert not bad, f"{page.name}: unknown Python fence tags {bad}: use ```{RUN_TAG} (executed) or ```{NORUN_TAG}"


def _check_api(ns, tmp_path, out):
    from pbdyn.outcome import OUTCOMES

    assert ns["result"].outcome in OUTCOMES
    assert ns["metrics"]["survivability"]["n_samples"] > 0
    assert ns["summary"].ran == 6
    trials = ns["trials"]
    assert len(trials) == 6 and {"metric_survivability", "start_x", "goal_x"} <= set(trials.columns)
    assert (tmp_path / "results" / "mine.sqlite").is_file() and (tmp_path / "trials.csv").is_file()
    assert "start - start: must be a sequence of numbers" in out                    # the ConfigError example


def _check_planners(ns, tmp_path, out):
    from pbdyn.outcome import OUTCOMES

    assert ns["result"].outcome in OUTCOMES
    assert "__main__:BeeLine" in out and "plan contract respected" in out          # check_planner's reports
    assert "plan broke speed at sample" in out
    assert not ns["report"].ok and "invalid_plan" in ns["report"].outcomes       # the last report: TooFast


def _check_results(ns, tmp_path, out):
    assert ns["result"].outcome == "success" and (tmp_path / "trial.png").is_file()


def _check_scenarios(ns, tmp_path, out):
    assert ns["sc"].world.dims == 3 and ns["world"].is_world
    assert "metric backend bullet" in out


def _check_metrics(ns, tmp_path, out):
    assert ns["exact"].n_samples > 0 and set(ns["baselines"]) == {"flux", "static_share"}


def _check_limits(ns, tmp_path, out):
    assert "obstacles.count" in out and "tracking.q" in out


def _check_architecture(ns, tmp_path, out):
    from pbdyn.outcome import OUTCOMES

    assert ns["result"].outcome in OUTCOMES and ns["ro"].dims == 2
    st = ns["st"]                          # the trial core driven with the acceleration action: inside the limits
    assert st.done and st.max_speed <= st.limits.v_max * (1 + 1e-9) and st.max_accel <= st.limits.a_max * (1 + 1e-9)


def _check_gym(ns, tmp_path, out):
    from pbdyn.outcome import OUTCOMES

    assert ns["easy"]["level"] == 1 and ns["hard"]["level"] > 1
    assert len(ns["curriculum"].history) >= 12 and "levels of the episodes" in out


CHECKS = {"api.md": _check_api, "gym.md": _check_gym, "planners.md": _check_planners, "results.md": _check_results,
          "scenarios.md": _check_scenarios, "difficulty-metrics.md": _check_metrics, "limits.md": _check_limits,
          "architecture.md": _check_architecture}
"""Page -> what its examples must have done (beyond running without an error)."""


@pytest.mark.parametrize("page", EXAMPLE_PAGES, ids=_ids(EXAMPLE_PAGES))
def test_page_python_examples_run(page, tmp_path, monkeypatch, capsys):
    ns = run_examples(page, tmp_path, monkeypatch)
    out = capsys.readouterr().out
    CHECKS[page.name](ns, tmp_path, out)


def test_every_page_with_examples_is_run_and_checked():
    assert set(CHECKS) == {p.name for p in EXAMPLE_PAGES}
    for name, runner in RUN_ELSEWHERE.items():
        assert python_blocks((DOCS / name).read_text(encoding="utf-8")), name
        text = (ROOT / runner).read_text(encoding="utf-8")
        assert f'"docs" / "{name}"' in text and "def test_the_benchmark_page_examples_run" in text, runner


# ------------------------------------------------------------------------------------------------ links
def slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation but '-' and '_' dropped, spaces as '-'."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading.strip())
    return re.sub(r"[^\w\- ]", "", text.lower()).replace(" ", "-")


def anchors(page: Path) -> set[str]:
    """The anchors of a Markdown page's headings (outside code blocks), duplicates numbered as GitHub does."""
    text = FENCE.sub("", page.read_text(encoding="utf-8"))
    seen: dict[str, int] = {}
    out = set()
    for m in re.finditer(r"^#{1,6} +(.+?) *#*$", text, re.M):
        s = slug(m.group(1))
        n = seen.get(s, 0)
        out.add(s if n == 0 else f"{s}-{n}")
        seen[s] = n + 1
    return out


def test_slugs_are_githubs():
    assert slug("Reproduction of the thesis' table 4-5") == "reproduction-of-the-thesis-table-4-5"
    assert slug("Maps of a chosen difficulty: `pbdyn generate`") == "maps-of-a-chosen-difficulty-pbdyn-generate"
    assert slug("What thesis_program still does differently") == "what-thesis_program-still-does-differently"


@pytest.mark.parametrize("page", [README_PATH, *PAGES], ids=["README.md", *_ids(PAGES)])
def test_relative_links_and_anchors_resolve(page):
    text = FENCE.sub("", page.read_text(encoding="utf-8"))
    bad = []
    for m in LINK.finditer(text):
        target = m.group(1)
        if re.match(r"[a-z]+:", target):
            continue                                   # http(s), mailto: not followed
        path, _, anchor = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        if not dest.is_file():
            bad.append(f"{target}: no file {dest}")
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            bad.append(f"{target}: {dest.name} has no heading with anchor #{anchor}")
    assert not bad, f"{page.name}: broken links {bad}"


def test_the_index_lists_every_page_and_the_readme_links_the_index():
    index = (DOCS / "README.md").read_text(encoding="utf-8")
    linked = {m.group(1).partition("#")[0] for m in LINK.finditer(index)}
    unlisted = [p.name for p in PAGES if p.name != "README.md" and p.name not in linked]
    assert not unlisted, f"docs/README.md does not list {unlisted}"
    assert "](docs/README.md)" in README_PATH.read_text(encoding="utf-8")


# ------------------------------------------------------------------------------------------------ the CLI page
def _cli_sections() -> dict[str, str]:
    text = (DOCS / "cli.md").read_text(encoding="utf-8")
    parts = re.split(r"^### pbdyn (\w+)\n", text, flags=re.M)
    return {name: re.split(r"^## ", body, flags=re.M)[0] for name, body in zip(parts[1::2], parts[2::2])}


def test_the_cli_page_lists_every_command_and_option():
    from pbdyn.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    sections = _cli_sections()
    assert set(sections) == set(sub.choices), "docs/cli.md needs one '### pbdyn <command>' section per command"
    page = (DOCS / "cli.md").read_text(encoding="utf-8")
    missing = [f"pbdyn {flag}" for action in parser._actions for flag in action.option_strings
               if flag.startswith("--") and flag != "--help" and f"`pbdyn {flag}`" not in page]
    for name, cmd in sub.choices.items():
        for action in cmd._actions:
            for flag in action.option_strings:
                if flag.startswith("--") and flag != "--help" and f"`{flag}" not in sections[name]:
                    missing.append(f"pbdyn {name} {flag}")
    assert not missing, f"docs/cli.md does not list {missing}"
