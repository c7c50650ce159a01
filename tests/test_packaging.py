"""Packaging: the models and bundled scenarios ship with the wheel, one resolver finds them, bundled scenarios by
name, LICENSE and CITATION.cff. The slow test installs the wheel into a fresh venv and flies from outside the
checkout."""

from __future__ import annotations

import configparser
import json
import os
import re
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
import setuptools

import pbdyn
from pbdyn import resources
from pbdyn.config import load_scenario
from pbdyn.errors import ConfigError
from tests.conftest import ROOT, SCENARIOS, pbdyn_cmd

OUTCOMES = ("success", "static_collision", "dynamic_collision", "freezing", "deadlock", "invalid_plan")
PTH_LINE = ('import importlib.util; importlib.util.find_spec("pbdyn_gym_hook") and '
            '__import__("pbdyn_gym_hook").install()\n')
"""The start-up line setup.py installs (pbdyn-gym.pth): the Gymnasium ids' hook, skipped if it cannot be found."""
PIP_OFFLINE_HINTS = ("No matching distribution", "Could not find a version", "Failed to establish a new connection",
                     "Temporary failure in name resolution")


def _setup_cfg() -> configparser.ConfigParser:
    cfg = configparser.ConfigParser()
    cfg.read(ROOT / "setup.cfg")
    return cfg


def _can_build_without_isolation() -> bool:
    major = int(setuptools.__version__.split(".")[0])
    minor = int(setuptools.__version__.split(".")[1])
    if (major, minor) >= (70, 1):  # bdist_wheel is part of setuptools from 70.1 on
        return True
    try:
        import wheel  # noqa: F401
    except ImportError:
        return False
    return True


def build_wheel(out: Path) -> Path:
    """Build pbdyn's wheel from the checkout into ``out``, its build/ and egg-info folders kept out of the checkout."""
    extra = out / "build.cfg"
    extra.write_text(f"[build]\nbuild_base = {out / 'build'}\n[egg_info]\negg_base = {out}\n")
    cmd = [sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "--disable-pip-version-check",
           "-w", str(out / "dist"), str(ROOT)]
    if _can_build_without_isolation():
        cmd.insert(4, "--no-build-isolation")
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300,
                          env={**os.environ, "DIST_EXTRA_CONFIG": str(extra)})
    if proc.returncode != 0:
        if any(h in proc.stderr for h in PIP_OFFLINE_HINTS):
            pytest.skip("pip cannot reach setuptools/wheel to build an isolated wheel (offline)")
        raise AssertionError(proc.stderr[-3000:])
    wheels = sorted((out / "dist").glob("pbdyn-*.whl"))
    assert len(wheels) == 1, wheels
    return wheels[0]


# ---------------------------------------------------------------------------------------------------------------
# the resolver, in the checkout
# ---------------------------------------------------------------------------------------------------------------
def test_resolver_uses_the_checkout_folders():
    assert resources.models_dir() == ROOT / "urdf"
    assert resources.scenarios_dir() == SCENARIOS
    assert resources.urdf_path("pillar") == resources.urdf_path("pillar.urdf") == ROOT / "urdf" / "pillar.urdf"
    names = resources.bundled_scenarios()
    assert {"quickstart", "datasets/controlled_2d", "worlds/warehouse_2d", "worlds/mixed_3d"} <= set(names)
    assert len(names) == len(list(SCENARIOS.rglob("*.toml")))
    with pytest.raises(ConfigError, match=r"^urdf: .*'nope'"):
        resources.urdf_path("nope")


def test_bundled_scenario_by_name(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for name in ("quickstart", "quickstart.toml"):
        sc = load_scenario(name)
        assert Path(sc.source) == SCENARIOS / "quickstart.toml" and sc.name == "quickstart"
    world = load_scenario("worlds/mixed_3d")
    assert world.resolve_path("urdf/gem.urdf") == SCENARIOS / "worlds" / "urdf" / "gem.urdf"
    assert world.resolve_path("box.urdf") == ROOT / "urdf" / "box.urdf"
    for bad in ("nope", "../quickstart", str(tmp_path / "quickstart.toml")):
        with pytest.raises(ConfigError) as exc:
            load_scenario(bad)
        msg = str(exc.value)
        assert msg.startswith("scenario: file not found") and repr(bad) in msg and "\n" not in msg


def test_a_local_file_wins_over_a_bundled_scenario(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "quickstart.toml").write_text('name = "mine"\n')
    assert load_scenario("quickstart.toml").name == "mine"
    assert load_scenario("quickstart").name == "mine"
    (tmp_path / "worlds").mkdir()
    (tmp_path / "worlds" / "warehouse_2d.toml").write_text('name = "my_world"\n')
    assert load_scenario("worlds/warehouse_2d").name == "my_world"


def test_cli_runs_a_bundled_scenario_by_name_and_reports_a_missing_one(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PBDYN_CACHE": str(tmp_path / "cache")}
    proc = subprocess.run(pbdyn_cmd() + ["run", "quickstart", "--json"], capture_output=True, text=True,
                          cwd=tmp_path, env=env, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["outcome"] in OUTCOMES
    proc = subprocess.run(pbdyn_cmd() + ["run", "no_such_scenario", "--json"], capture_output=True, text=True,
                          cwd=tmp_path, env=env, timeout=300)
    assert proc.returncode == 2 and proc.stdout == ""
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "no_such_scenario" in lines[0] and "Traceback" not in proc.stderr


# ---------------------------------------------------------------------------------------------------------------
# metadata
# ---------------------------------------------------------------------------------------------------------------
def test_setup_cfg_lists_every_package():
    cfg = _setup_cfg()
    listed = set(cfg["options"]["packages"].split())
    found = set(setuptools.find_packages(str(ROOT), include=["pbdyn", "pbdyn.*"]))
    assert found <= listed, f"add to setup.cfg [options] packages: {sorted(found - listed)}"
    assert {"pbdyn.models", "pbdyn.scenarios"} <= listed


def test_license_and_citation():
    assert (ROOT / "LICENSE").read_text().startswith("MIT License\n\nCopyright (c) 2026 the pbdyn developers\n")
    assert _setup_cfg()["metadata"]["license"] == "MIT"
    cff = (ROOT / "CITATION.cff").read_text()
    assert re.search(r"^cff-version: 1\.2\.0$", cff, re.M)
    assert re.search(rf"^version: {re.escape(pbdyn.__version__)}$", cff, re.M)
    assert re.search(r"^license: MIT$", cff, re.M) and re.search(r"^date-released: 2026-11-23$", cff, re.M)
    assert '- name: "The pbdyn developers"' in cff


# ---------------------------------------------------------------------------------------------------------------
# make demo / make test: what each installs
# ---------------------------------------------------------------------------------------------------------------
def _make_dry_run(folder: Path, target: str, *stamps: str) -> list[str]:
    """The commands `make -n TARGET` would run in a fresh clone (no .venv; made in ``folder``) holding the
    repository's Makefile, or with the given stamp files of an earlier install."""
    import shutil

    if shutil.which("make") is None:
        pytest.skip("no make on this machine")
    clone = folder
    for rel in ("Makefile", "setup.cfg", "setup.py", "pyproject.toml", "tools/install_sysdeps.sh",
                "pbdyn/planning/primitives/native/ruckig_batch.cpp", "pbdyn/planning/primitives/native/build.py"):
        (clone / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / rel, clone / rel)
    for stamp in stamps:
        (clone / ".venv").mkdir(exist_ok=True)
        (clone / ".venv" / stamp).touch()
    env = {k: v for k, v in os.environ.items() if k not in ("MAKEFLAGS", "MAKELEVEL", "MFLAGS", "MAKEOVERRIDES")}
    done = subprocess.run(["make", "--no-print-directory", "-n", target], cwd=clone, capture_output=True, text=True,
                          timeout=60, env=env)   # under `make test` the outer make's flags would add directory lines
    assert done.returncode == 0, done.stderr
    return done.stdout.splitlines()


def test_make_demo_installs_what_the_demo_needs_and_no_test_tooling(tmp_path):
    demo = _make_dry_run(tmp_path / "a", "demo")
    quiet = 'PYTHONWARNINGS="ignore:Editable installation" '     # setuptools' notice for developers, not users
    assert "bash tools/install_sysdeps.sh" in demo and quiet + ".venv/bin/python -m pip install --quiet -e ." in demo
    assert not [c for c in demo if "[test]" in c or "--test" in c or "chromium" in c or "playwright" in c], demo
    assert demo[-2:] == [".venv/bin/pbdyn batch scenarios/quickstart.toml --out results/quickstart.sqlite",
                         ".venv/bin/pbdyn evaluate results/quickstart.sqlite --plots results/quickstart-figures"]
    test = _make_dry_run(tmp_path / "b", "test")
    assert test.index(quiet + ".venv/bin/python -m pip install --quiet -e '.[test]'") \
        < test.index("bash tools/install_sysdeps.sh --test") < len(test) - 1
    assert test[-1].startswith(".venv/bin/python -m pytest ")
    after_demo = _make_dry_run(tmp_path / "c", "test", ".installed", ".native")   # `make demo`, then `make test`
    assert after_demo and after_demo[0] == quiet + ".venv/bin/python -m pip install --quiet -e '.[test]'"


def test_install_sysdeps_lists_the_browser_only_for_the_tests():
    script = (ROOT / "tools" / "install_sysdeps.sh").read_text()
    assert subprocess.run(["bash", "-n", str(ROOT / "tools" / "install_sysdeps.sh")]).returncode == 0
    runtime, tests = script.split("need=()", 1)[1].split('if [ "$test_deps" -eq 1 ]; then', 1)
    assert "libusb-1.0-0" in runtime and "need+=(g++)" in runtime
    assert not any(word in runtime for word in ("chromium", "xvfb", "playwright"))
    assert "need+=(chromium)" in tests and "need+=(chromium-driver)" in tests and "need+=(xvfb)" in tests
    for args in ([], ["--test"]):
        done = subprocess.run(["bash", str(ROOT / "tools" / "install_sysdeps.sh"), *args, "--dry-run"],
                              capture_output=True, text=True, timeout=60)
        assert done.returncode == 0 and done.stdout.startswith("missing: ") and done.stderr == "", done
        if not args:
            assert not {"chromium", "chromium-driver", "xvfb"} & set(done.stdout.split()[1:])
    bad = subprocess.run(["bash", str(ROOT / "tools" / "install_sysdeps.sh"), "--browser"], capture_output=True,
                         text=True, timeout=60)
    assert bad.returncode == 2 and "usage" in bad.stderr


def test_the_demo_commands_need_no_test_extras(tmp_path):
    """`make demo` installs pbdyn without its test extras: the demo's batch and evaluation (with figures) run with
    pytest, selenium and jsonschema unimportable."""
    code = ("import sys\nfor m in ('pytest', 'selenium', 'jsonschema', 'xdist'):\n    sys.modules[m] = None\n"
            "from pbdyn.cli import main\n"
            "if __name__ == '__main__':\n"
            f"    assert main(['batch', 'quickstart', '--out', {str(tmp_path / 'q.sqlite')!r}, '--limit', '3',"
            " '--workers', '1']) == 0\n"
            f"    assert main(['evaluate', {str(tmp_path / 'q.sqlite')!r}, '--bootstrap', '20', '--plots', "
            f"{str(tmp_path / 'figs')!r}]) == 0\n")
    (tmp_path / "demo.py").write_text(code)
    done = subprocess.run([sys.executable, str(tmp_path / "demo.py")], cwd=tmp_path, capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    assert list((tmp_path / "figs").iterdir())


# ---------------------------------------------------------------------------------------------------------------
# the wheel
# ---------------------------------------------------------------------------------------------------------------
@pytest.mark.timeout(120)
def test_wheel_carries_models_and_bundled_scenarios(tmp_path):
    wheel = build_wheel(tmp_path)
    names = set(zipfile.ZipFile(wheel).namelist())
    expected = {f"pbdyn/models/{p.name}" for p in (ROOT / "urdf").glob("*.urdf")}
    expected |= {"pbdyn/scenarios/" + p.relative_to(SCENARIOS).as_posix()
                 for p in SCENARIOS.rglob("*") if p.is_file() and "__pycache__" not in p.parts}
    expected |= {p.relative_to(ROOT).as_posix() for p in (ROOT / "pbdyn").rglob("*.py")}
    assert {"pbdyn/models/quadrotor.urdf", "pbdyn/scenarios/quickstart.toml", "pbdyn/scenarios/worlds/meshes/gem.obj",
            "pbdyn/scenarios/worlds/urdf/gem.urdf", "pbdyn/scenarios/datasets/controlled_2d.toml"} <= expected
    expected.add("pbdyn/planning/primitives/native/ruckig_batch.cpp")   # the native batch's source, built on the target
    assert not expected - names, sorted(expected - names)
    assert not [n for n in names if n.endswith(".so")]              # never a library built for this machine
    tops = {n.split("/")[0] for n in names}
    assert tops == {"pbdyn", "pbdyn_gym_hook.py", "pbdyn-gym.pth", wheel.name.split("-py")[0] + ".dist-info"}, tops
    dist_info = next(t for t in tops if t.endswith(".dist-info"))
    assert any(n.startswith(dist_info) and n.endswith("/LICENSE") for n in names)
    metadata = zipfile.ZipFile(wheel).read(f"{dist_info}/METADATA").decode()
    assert "License-File: LICENSE" in metadata
    _the_wheels_start_up_hook_registers_the_gym_ids(wheel, out=tmp_path / "unpacked")


def _the_wheels_start_up_hook_registers_the_gym_ids(wheel: Path, out: Path) -> None:
    """The wheel's pbdyn-gym.pth, processed as site-packages' .pth files are, makes gymnasium.make find pbdyn's ids.

    The interpreter starts without site (-S), so that only the unpacked wheel's .pth runs; the test environment's
    packages are put on the path without running theirs."""
    zipfile.ZipFile(wheel).extractall(out)
    assert (out / "pbdyn-gym.pth").read_text() == PTH_LINE
    deps = [p for p in sys.path if p.endswith("site-packages")]
    code = (f"import sys, site; sys.path.extend({deps!r}); site.addsitedir({str(out)!r})\n"
            "import gymnasium, pbdyn\n"
            f"assert pbdyn.__file__.startswith({str(out)!r}), pbdyn.__file__\n"
            "env = gymnasium.make('pbdyn/Avoid2D-v0'); env.reset(seed=0); env.close()\n")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PBDYN_GYM_AUTOREGISTER")}
    done = subprocess.run([sys.executable, "-S", "-c", code], capture_output=True, text=True, cwd=out, env=env,
                          timeout=300)
    assert done.returncode == 0 and not done.stderr, done.stderr[-3000:]


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_installed_wheel_flies_a_bundled_scenario_outside_the_checkout(tmp_path):
    wheel = build_wheel(tmp_path)
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    py, pbdyn_exe = venv / "bin" / "python", venv / "bin" / "pbdyn"
    install = subprocess.run([str(py), "-m", "pip", "install", "--quiet", "--disable-pip-version-check", str(wheel)],
                             capture_output=True, text=True, timeout=1500)
    if install.returncode != 0 and any(h in install.stderr for h in PIP_OFFLINE_HINTS):
        pytest.skip("pip cannot install pbdyn's dependencies (offline, not in its cache)")
    assert install.returncode == 0, install.stderr[-3000:]
    cwd = tmp_path / "elsewhere"
    cwd.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["PBDYN_CACHE"] = str(tmp_path / "cache")

    def run(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run(list(args), capture_output=True, text=True, cwd=cwd, env=env, timeout=600)

    where = run(str(py), "-c", "import pbdyn.resources as r; print(r.models_dir()); print(r.scenarios_dir())")
    assert where.returncode == 0 and len(where.stdout.split()) == 2, where.stderr
    site = venv.resolve()
    for line in where.stdout.split():
        assert Path(line).resolve().is_relative_to(site) and not Path(line).resolve().is_relative_to(ROOT), line

    proc = run(str(pbdyn_exe), "run", "quickstart", "--json")
    assert proc.returncode == 0, proc.stderr[-3000:]
    row = json.loads(proc.stdout)
    assert row["outcome"] in OUTCOMES
    assert row["planner"] and row["flight_time_s"] > 0 and len(row["config_hash"]) == 64

    proc = run(str(pbdyn_exe), "metrics", "worlds/warehouse_2d", "--json")
    assert proc.returncode == 0, proc.stderr[-3000:]
    doc = json.loads(proc.stdout)
    assert doc["scenario"] == "warehouse_2d" and len(doc["bodies"]) == 14
    assert doc["metrics"] and all(m["value"] is not None for m in doc["metrics"].values())

    proc = run(str(pbdyn_exe), "metrics", "worlds/mixed_3d", "--metric", "density", "--json")  # a mesh URDF
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert json.loads(proc.stdout)["metrics"]["density"]["value"] > 0

    proc = run(str(pbdyn_exe), "run", "no_such_scenario")
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_editable_install_maps_the_data_packages(tmp_path):
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    py = venv / "bin" / "python"
    extra = tmp_path / "build.cfg"
    extra.write_text(f"[build]\nbuild_base = {tmp_path / 'build'}\n[egg_info]\negg_base = {tmp_path}\n")
    install = subprocess.run([str(py), "-m", "pip", "install", "--quiet", "--disable-pip-version-check", "--no-deps",
                              "-e", str(ROOT)], capture_output=True, text=True, timeout=300,
                             env={**os.environ, "DIST_EXTRA_CONFIG": str(extra)})
    if install.returncode != 0 and any(h in install.stderr for h in PIP_OFFLINE_HINTS):
        pytest.skip("pip cannot reach setuptools/wheel to build an editable install (offline)")
    assert install.returncode == 0, install.stderr[-3000:]
    code = ("import importlib.resources as r, pbdyn.resources as p; "
            "print(r.files('pbdyn.models'), r.files('pbdyn.scenarios'), p.models_dir(), p.scenarios_dir())")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    proc = subprocess.run([str(py), "-c", code], capture_output=True, text=True, cwd=tmp_path, env=env, timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    models, scenarios, models2, scenarios2 = map(Path, proc.stdout.split())
    assert models == models2 == ROOT / "urdf" and scenarios == scenarios2 == SCENARIOS
    hooks = list(venv.glob("lib/python*/site-packages/pbdyn-gym.pth"))      # the Gymnasium ids' start-up hook
    assert len(hooks) == 1 and hooks[0].read_text() == PTH_LINE
