"""Every command's error for a bad value names the flag as the user typed it (docs/design.md "Command line").

The walk covers every option of every subcommand of pbdyn.cli.build_parser(): each takes a bad value (or a misuse,
for a switch that needs another) and must give exit status 2 and one line ``pbdyn: error: FLAG...``; a new option
without a case here fails test_every_option_of_every_command_has_a_case.
"""

from __future__ import annotations

import argparse
import ast
import re
from pathlib import Path

import pytest

from pbdyn.cli import build_parser
from tests.fuzz_io import SMALL_SCENARIO, cli

SWITCHES = {"--json", "--gui", "--dense", "--extend", "--no-metrics", "--rerun-changed", "--retry-errors", "--pool",
            "--reproduce", "--list", "--help", "--version"}
"""Options that take no value and need no other option: nothing to get wrong."""

GEN = ["generate", "--metric", "density", "--target", "1", "--tolerance", "0.1", "--out", "{tmp}/g.toml"]
BENCH = ["bench", "straight_line", "--out", "{tmp}/bench"]

CASES = [
    ("run", "--planner", ["run", "quickstart", "--planner", "nope"]),
    ("run", "--gaze", ["run", "quickstart", "--gaze", "nope"]),
    ("run", "--map", ["run", "quickstart", "--map", "999999"]),
    ("run", "--start", ["run", "quickstart", "--start", "a,b"]),
    ("run", "--goal", ["run", "quickstart", "--goal", "1"]),
    ("run", "--vmax", ["run", "quickstart", "--vmax", "nan"]),
    ("run", "--follow", ["run", "quickstart", "--follow"]),
    ("run", "--gui-snapshot", ["run", "quickstart", "--gui-snapshot", "{tmp}/x.txt"]),
    ("run", "--trace", ["run", "quickstart", "--trace", "{tmp}/x.txt"]),
    ("run", "--replay", ["run", "quickstart", "--replay", "{tmp}/x.txt"]),
    ("replay", "--out", ["replay", "{tmp}/afile.txt", "--out", "{tmp}/x.txt"]),
    ("replay", "--fps", ["replay", "{tmp}/afile.txt", "--out", "{tmp}/x.gif", "--fps", "-1"]),
    ("replay", "--every", ["replay", "{tmp}/afile.txt", "--out", "{tmp}/x.gif", "--every", "0"]),
    ("rollout", "--map", ["rollout", "quickstart", "--out", "{tmp}/r.npz", "--map", "999999"]),
    ("rollout", "--out", ["rollout", "quickstart", "--out", "{tmp}/x.txt"]),
    ("rollout", "--horizon", ["rollout", "quickstart", "--out", "{tmp}/r.npz", "--horizon", "inf"]),
    ("metrics", "--map", ["metrics", "quickstart", "--map", "999999"]),
    ("metrics", "--metric", ["metrics", "quickstart", "--metric", "nope"]),
    ("metrics", "--backend", ["metrics", "quickstart", "--backend", "nope"]),
    ("metrics", "--plot", ["metrics", "quickstart", "--plot", "{tmp}/x.txt"]),
    ("demo", "--maps", ["demo", "quickstart", "--maps", "0"]),
    ("demo", "--pairs", ["demo", "quickstart", "--pairs", "0"]),
    ("batch", "--out", ["batch", "quickstart", "--out", "{tmp}/afile.txt"]),
    ("batch", "--workers", ["batch", "quickstart", "--out", "{tmp}/b.db", "--workers", "0"]),
    ("batch", "--scheduler", ["batch", "quickstart", "--out", "{tmp}/b.db", "--scheduler", "nope"]),
    ("batch", "--limit", ["batch", "quickstart", "--out", "{tmp}/b.db", "--limit", "0"]),
    ("batch", "--shard", ["batch", "quickstart", "--out", "{tmp}/b.db", "--shard", "3/2"]),
    ("batch", "--lockstep", ["batch", "quickstart", "--out", "{tmp}/b.db", "--lockstep", "0"]),
    ("merge", "--out", ["merge", "{store}", "--out", "{tmp}/afile.txt"]),
    ("evaluate", "--plots", ["evaluate", "{store}", "--plots", "{tmp}/afile.txt"]),
    ("evaluate", "--html", ["evaluate", "{store}", "--html", "{tmp}/x.txt"]),
    ("evaluate", "--bootstrap", ["evaluate", "{store}", "--bootstrap", "-5"]),
    ("export", "--csv", ["export", "{store}", "--csv", "{tmp}"]),
    ("export", "--parquet", ["export", "{store}", "--parquet", "{tmp}"]),
    ("generate", "--metric", ["generate", "--metric", "nope", "--target", "1", "--tolerance", "0.1", "--out",
                              "{tmp}/g.toml"]),
    ("generate", "--target", ["generate", "--metric", "density", "--target", "nan", "--tolerance", "0.1", "--out",
                              "{tmp}/g.toml"]),
    ("generate", "--success", ["generate", "--success", "2", "--tolerance", "0.1", "--out", "{tmp}/g.toml"]),
    ("generate", "--tolerance", ["generate", "--metric", "density", "--target", "1", "--tolerance", "-1", "--out",
                                 "{tmp}/g.toml"]),
    ("generate", "--count", GEN + ["--count", "0"]),
    ("generate", "--out", GEN[:-1] + ["{tmp}/x.txt"]),
    ("generate", "--family", GEN + ["--family", "nope"]),
    ("generate", "--dims", GEN + ["--dims", "4"]),
    ("generate", "--scenario", GEN + ["--scenario", "nope"]),
    ("generate", "--obstacles", GEN + ["--obstacles", "0"]),
    ("generate", "--radius", GEN + ["--radius", "1e6"]),
    ("generate", "--speed", GEN + ["--speed", "1e6"]),
    ("generate", "--seed", GEN + ["--seed", "-1"]),
    ("generate", "--workers", GEN + ["--workers", "0"]),
    ("calibrate", "--map", ["calibrate", "quickstart", "--map", "999999"]),
    ("calibrate", "--store", ["calibrate", "quickstart", "--store", "{tmp}/afile.txt"]),
    ("calibrate", "--workers", ["calibrate", "quickstart", "--workers", "0"]),
    ("bench", "--gaze", BENCH + ["--gaze", "nope"]),
    ("bench", "--params", BENCH + ["--params", '{"zz": 1}']),
    ("bench", "--gaze-params", BENCH + ["--gaze-params", '{"zz": 1}']),
    ("bench", "--failures", BENCH + ["--failures", "0"]),
    ("bench", "--failures-format", BENCH + ["--failures-format", "webm"]),
    ("bench", "--suite", BENCH + ["--suite", "nope"]),
    ("bench", "--workers", BENCH + ["--workers", "0"]),
    ("bench", "--scheduler", BENCH + ["--scheduler", "nope"]),
    ("bench", "--out", ["bench", "straight_line", "--out", "{tmp}/afile.txt"]),
    ("bench", "--compare", ["bench", "--compare", "{tmp}/afile.txt"]),
]


def _options() -> set[tuple[str, str]]:
    """(command, option) of every option of every subcommand."""
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return {(command, action.option_strings[0]) for command, p in sub.choices.items() for action in p._actions
            if action.option_strings and not set(action.option_strings) & SWITCHES}


def flags_of(command: str) -> set[str]:
    """Every option string of ``command`` (switches included)."""
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return {o for action in sub.choices[command]._actions for o in action.option_strings}


ADVISED = re.compile(r"(?<![\w-])(--[a-z][a-z-]*)")
OTHER_COMMAND = re.compile(r"pbdyn [a-z]+ --[a-z][a-z-]*")


def foreign_flags(command: str, message: str) -> set[str]:
    """The flags ``message`` names that ``command`` does not have ("pbdyn OTHER --flag", which names its command,
    excepted; "--flag.key" names a key of the flag's value)."""
    return set(ADVISED.findall(OTHER_COMMAND.sub("", message))) - flags_of(command)


def test_every_option_of_every_command_has_a_case():
    assert _options() == {(command, flag) for command, flag, _ in CASES}


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("flags")
    (tmp / "afile.txt").write_text("not a store, trace or card\n")
    (tmp / "small.toml").write_text(SMALL_SCENARIO)
    store = tmp / "small.db"
    code, _, err, _ = cli(["batch", str(tmp / "small.toml"), "--out", str(store), "--limit", "1", "--no-metrics",
                           "--workers", "1"])
    assert code == 0, err
    return {"tmp": str(tmp), "store": str(store)}


@pytest.mark.parametrize("command,flag,argv", CASES, ids=[f"{c}{f}" for c, f, _ in CASES])
def test_a_bad_value_names_the_flag_as_typed(files, command, flag, argv):
    code, out, err, _ = cli([a.replace("{tmp}", files["tmp"]).replace("{store}", files["store"]) for a in argv])
    assert code == 2 and out == "" and err.count("\n") == 1, (code, err)
    named = (f"{flag}: ", f"{flag}.", f"argument {flag}: ")   # --params.KEY names the key of the flag's JSON
    assert any(err.startswith("pbdyn: error: " + n) for n in named), err
    assert not foreign_flags(command, err), err          # advice names only flags the command has


BENCH_REACHES = ["pbdyn/experiments/runner.py", "pbdyn/experiments/plan.py", "pbdyn/experiments/extend.py",
                 "pbdyn/experiments/store.py", "pbdyn/experiments/dispatch.py", "pbdyn/experiments/pool.py",
                 "pbdyn/experiments/cluster.py", "pbdyn/experiments/signals.py", "pbdyn/experiments/mainguard.py",
                 "pbdyn/experiments/tasks.py", "pbdyn/analysis/replay.py", "pbdyn/benchmark/run.py",
                 "pbdyn/benchmark/suite.py", "pbdyn/benchmark/failures.py", "pbdyn/benchmark/cost.py",
                 "pbdyn/planning/registry.py", "pbdyn/errors.py"]
"""The modules whose ConfigErrors `pbdyn bench` can raise (the batch runner's through bench's terms,
pbdyn.benchmark.run.bench_error); not shards.py (bench never shards) nor calibrate or generate."""


def _message_texts(path: Path):
    """Every string of ``path`` that is not documentation (a docstring, a string statement) nor a pattern
    (re.compile), an f-string's constant parts joined with "{}", and whether it is a message of a ConfigError naming
    SCENARIO (which bench words itself); implicitly joined literals are one."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    docs, scenario = set(), set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant):   # docstrings, attribute docs
            docs.add(id(node.value))
        if isinstance(node, ast.Call) and getattr(node.func, "attr", None) == "compile":       # re.compile(...)
            docs.update(id(n) for a in node.args for n in ast.walk(a))
        if isinstance(node, ast.Call) and getattr(node.func, "id", getattr(node.func, "attr", None)) == "ConfigError" \
                and node.args and isinstance(node.args[0], ast.Constant) and node.args[0].value == "SCENARIO":
            scenario.update(id(n) for a in node.args[1:] for n in ast.walk(a))
    parts = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.JoinedStr):
            parts.update(id(v) for v in node.values)
            yield "".join(v.value if isinstance(v, ast.Constant) else "{}" for v in node.values), id(node) in scenario
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docs | parts:
            yield node.value, id(node) in scenario


def test_every_error_bench_can_reach_advises_only_bench_flags():
    """Static: every message of the modules `pbdyn bench` runs (their strings, docstrings aside), as bench words it
    (bench_error, then the command line's words, pbdyn.cli._cli_words), names only flags bench has and never asks
    for a file where bench takes a folder (--out)."""
    from pbdyn.benchmark.run import _OUT_FILE
    from pbdyn.cli import _cli_words

    root = Path(__file__).resolve().parents[1]
    seen = 0
    for rel in BENCH_REACHES:
        for message, of_scenario in _message_texts(root / rel):
            if of_scenario:                  # bench_error words a store of another scenario itself
                continue
            worded = _cli_words("bench", _OUT_FILE.sub("another `out` folder", message))
            assert not foreign_flags("bench", worded), (rel, message)
            assert "--out file" not in worded, (rel, message)
            seen += "--" in worded
    assert seen >= 10                        # the walk found the runner's advice


def test_library_errors_name_options_not_flags():
    """Static: no error or warning raised below pbdyn/cli.py names a flag or a command line ("--out", "pbdyn
    batch"): a library message names an option by its library name in backticks (`rerun_changed`), which the
    command line writes as the flag (pbdyn.cli._cli_words)."""
    from pbdyn.cli import COMMANDS

    words = re.compile(r"(?<![\w-])--[a-z][\w-]*|\bpbdyn (?:%s)\b" % "|".join(COMMANDS))
    root = Path(__file__).resolve().parents[1]
    found = []
    for path in sorted((root / "pbdyn").rglob("*.py")):
        if path == root / "pbdyn" / "cli.py":
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            name = getattr(node, "func", None)
            name = getattr(name, "id", None) or getattr(name, "attr", None) or ""
            if isinstance(node, ast.Call) and name.endswith(("Error", "Warning")):
                text = " ".join(n.value for n in ast.walk(node)
                                if isinstance(n, ast.Constant) and isinstance(n.value, str))
                if words.search(text):
                    found.append(f"{path.relative_to(root)}:{node.lineno}")
    assert not found
