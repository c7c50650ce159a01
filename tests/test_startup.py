"""What a pbdyn process pays before its first trial, and scripts that start worker pools.

`pbdyn --version`; modules and numba loaded only by the commands that use them (pbdyn.jit's deferred decoration,
the planner registry's lazy imports, a batch coordinator without numba); the native library's probe run once per
installed build (a stamp in the cache); a script calling run_batch at its top level without
``if __name__ == "__main__":`` fails at once with one line (pbdyn.experiments.mainguard), a guarded one works."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("numba", "llvmlite", "scipy", "pandas", "cvxpy", "open3d", "dask", "matplotlib", "statsmodels", "sklearn")


def _python(*args, cwd: Path = ROOT, env: dict | None = None, timeout: float = 300) -> subprocess.CompletedProcess:
    full = {k: v for k, v in os.environ.items() if k not in ("PBDYN_POOL_REPORT", "PBDYN_NATIVE_REPORTED")}
    full["PYTHONPATH"] = os.pathsep.join([str(ROOT), full.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    full.update(env or {})
    return subprocess.run([sys.executable, *args], cwd=cwd, env=full, capture_output=True, text=True,
                          timeout=timeout)


def _loaded(code: str, **kw) -> set[str]:
    """The HEAVY modules loaded after running ``code`` in a fresh interpreter."""
    probe = code + f"\nimport sys, json\nprint(json.dumps([m for m in {HEAVY!r} if m in sys.modules]))"
    done = _python("-c", probe, **kw)
    assert done.returncode == 0, done.stderr
    return set(json.loads(done.stdout.strip().splitlines()[-1]))


# ----------------------------------------------------------------------------------------------- --version
def test_version_is_one_line_and_loads_nothing_heavy():
    import pbdyn

    done = _python("-m", "pbdyn", "--version")
    assert (done.returncode, done.stdout, done.stderr) == (0, f"pbdyn {pbdyn.__version__}\n", "")
    code = ("import sys\nfrom pbdyn.cli import main\ntry:\n    main(['--version'])\nexcept SystemExit as e:\n"
            "    assert e.code == 0\nassert 'pbdyn.api' not in sys.modules and 'numpy' not in sys.modules")
    assert _loaded(code) == set()


# ----------------------------------------------------------------------------------------------- lazy loading
def test_the_planner_registry_loads_only_the_planners_asked_for():
    code = textwrap.dedent("""
        import sys
        from pbdyn.planning import registry
        assert 'pbdyn.planning.mpc.planner' not in sys.modules
        assert 'pbdyn.planning.primitives.global_astar' not in sys.modules
        assert sorted(registry.TRAJECTORY_PLANNERS) == ['global_primitives', 'local_primitives',
                                                        'local_primitives_minjerk', 'mpc', 'straight_line']
        cls = registry.resolve_trajectory_planner('straight_line')
        from pbdyn.planning.straight_line import StraightLine
        assert cls is StraightLine and registry.GAZE_PLANNERS['lookahead'].__name__ == 'LookAhead'
        assert 'pbdyn.planning.mpc.planner' not in sys.modules
    """)
    assert _loaded(code) == set()


def test_building_the_quickstart_planners_loads_neither_numba_nor_the_native_library():
    """What `pbdyn batch`'s coordinator does before its workers fly (runner.check_planners): numba, scipy and the
    native library stay unloaded; the planner probes them when it first plans."""
    code = textwrap.dedent("""
        import pbdyn
        from pbdyn.experiments.runner import check_planners
        from pbdyn.planning.primitives import native
        check_planners(pbdyn.load_scenario('quickstart'))
        assert native.ruckig_build_address.cache_info().currsize == 0
    """)
    assert _loaded(code) == set()


def test_a_batch_coordinator_does_not_load_numba(tmp_path):
    """`pbdyn batch` with one worker: the coordinator (this process) never imports numba or scipy; the worker does
    the compiled work."""
    code = textwrap.dedent(f"""
        import pbdyn
        if __name__ == '__main__':
            s = pbdyn.run_batch('quickstart', {str(tmp_path / 'r.sqlite')!r}, limit=2, workers=1, progress=False)
            assert (s.ran, s.errors, s.maps_computed) == (2, 0, 1), s
    """)
    script = tmp_path / "coordinator.py"
    script.write_text(code + "\n    import sys, json\n    print(json.dumps([m for m in "
                      f"{HEAVY[:3]!r} if m in sys.modules]))\n")
    done = _python(str(script), cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout.strip().splitlines()[-1]) == []


def test_deferred_njit_compiles_on_first_call_and_swaps_in_the_dispatcher(tmp_path):
    """pbdyn.jit: numba is imported by the first call; then the module holds numba's dispatchers (a compiled
    caller sees them as globals, inline='always' helpers included) and results equal numba's own decoration."""
    mod = tmp_path / "deferred_mod.py"
    mod.write_text(textwrap.dedent("""
        import numpy as np
        from pbdyn.jit import njit

        @njit(inline="always")
        def _sq(x):
            return x * x

        @njit(cache=False)
        def total(a):
            s = 0.0
            for x in a:
                s += _sq(x)
            return s
    """))
    code = textwrap.dedent("""
        import sys, pickle
        import numpy as np
        import deferred_mod
        import pbdyn.jit as jit
        assert 'numba' not in sys.modules and not jit.loaded()
        stand_in = deferred_mod.total
        a = np.arange(5.0)
        assert stand_in(a) == 30.0 and jit.loaded()
        from numba.core.dispatcher import Dispatcher
        assert isinstance(deferred_mod.total, Dispatcher) and isinstance(deferred_mod._sq, Dispatcher)
        assert stand_in(a) == deferred_mod.total(a) and stand_in.py_func is deferred_mod.total.py_func
        assert pickle.loads(pickle.dumps(stand_in)) is deferred_mod.total
        import numba
        @numba.njit
        def caller(a):                  # a stand-in kept elsewhere is typed as its dispatcher
            return stand_in(a) + 1.0
        assert caller(a) == 31.0
        later = jit.njit(lambda x: x + 1)
        assert isinstance(later, Dispatcher) and later(1) == 2
    """)
    done = _python("-c", code, env={"PYTHONPATH": os.pathsep.join([str(tmp_path), str(ROOT)])})
    assert done.returncode == 0, done.stderr


# ----------------------------------------------------------------------------------------------- native probe
@pytest.fixture
def native_fresh(monkeypatch, tmp_path):
    """pbdyn.planning.primitives.native with its per-process answer forgotten, the cache in tmp_path, and agrees()
    counted."""
    from pbdyn.planning.primitives import native

    if not (native.LIBRARY.is_file() and native.integrity_problem(native.LIBRARY) is None):
        pytest.skip("the native ruckig batch is not built here")
    monkeypatch.setenv("PBDYN_CACHE", str(tmp_path / "cache"))
    monkeypatch.delenv("PBDYN_NATIVE", raising=False)
    monkeypatch.delenv(native._REPORTED, raising=False)
    calls = []
    real = native.agrees

    def counted(lib, *a, **k):
        calls.append(1)
        return real(lib, *a, **k)

    monkeypatch.setattr(native, "agrees", counted)
    native.ruckig_build_address.cache_clear()
    yield native, calls
    native.ruckig_build_address.cache_clear()


def test_the_native_probe_runs_once_per_build_and_environment(native_fresh, tmp_path):
    native, calls = native_fresh
    first = native.ruckig_build_address()
    assert first is not None and len(calls) == 1
    stamps = list((tmp_path / "cache" / "native").iterdir())
    assert len(stamps) == 1 and "agrees with ruckig" in stamps[0].read_text()
    native.ruckig_build_address.cache_clear()
    assert native.ruckig_build_address() is not None and len(calls) == 1       # the stamp: no second probe
    # another build or environment is another key: probed again
    key = native.agreement_key("0" * 64, "0.0.0")
    assert key != native.agreement_key(stamps[0].name, "0.0.0") and len(key) == 64
    stamps[0].unlink()
    native.ruckig_build_address.cache_clear()
    assert native.ruckig_build_address() is not None and len(calls) == 2


def test_a_library_that_disagrees_is_never_stamped(native_fresh, monkeypatch, tmp_path, capsys):
    native, calls = native_fresh
    monkeypatch.setattr(native, "agrees", lambda lib, *a, **k: calls.append(1) or False)
    assert native.ruckig_build_address() is None and len(calls) == 1
    assert "differs from the ruckig Python package" in capsys.readouterr().err
    assert not (tmp_path / "cache" / "native").exists()


def test_an_unwritable_cache_probes_every_time_quietly(native_fresh, monkeypatch, tmp_path, capsys):
    native, calls = native_fresh
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    monkeypatch.setenv("PBDYN_CACHE", str(blocker / "cache"))
    for _ in range(2):
        native.ruckig_build_address.cache_clear()
        assert native.ruckig_build_address() is not None
    assert len(calls) == 2 and capsys.readouterr().err == ""


# ----------------------------------------------------------------------------------------------- main guard
UNGUARDED = """
import pbdyn

def fly():
    pbdyn.{call}

fly()
print("should not get here")
"""
GUARDED = """
import pbdyn

if __name__ == "__main__":
    s = pbdyn.{call}
    print("done", s.ran, s.errors)
"""
BATCH = "run_batch('quickstart', {out!r}, limit=2, workers={workers}, progress=False, metrics=False)"


@pytest.mark.parametrize("workers", [1, 2])
def test_a_script_without_the_main_guard_fails_at_once_with_one_line(tmp_path, workers):
    out = tmp_path / "r.sqlite"
    script = tmp_path / "unguarded.py"
    script.write_text(UNGUARDED.format(call=BATCH.format(out=str(out), workers=workers)))
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    t0 = time.monotonic()
    done = _python(str(script), cwd=tmp_path, env={"TMPDIR": str(tmp)}, timeout=120)
    lines = done.stderr.splitlines()
    assert done.returncode != 0 and done.stdout == "", (done.returncode, done.stdout, done.stderr)
    assert len(lines) == 1 and lines[0].startswith("pbdyn: error: run_batch: was called at the top level of "), lines
    assert str(script) in lines[0] and 'if __name__ == "__main__":' in lines[0]
    assert time.monotonic() - t0 < 60
    assert not out.exists() and not list(tmp_path.glob("r.sqlite*"))          # no store left behind
    assert not list(tmp.iterdir())                                             # nor the workers' report


def test_the_same_script_with_the_main_guard_works(tmp_path):
    script = tmp_path / "guarded.py"
    script.write_text(GUARDED.format(call=BATCH.format(out=str(tmp_path / "r.sqlite"), workers=2)))
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    done = _python(str(script), cwd=tmp_path, env={"TMPDIR": str(tmp)})
    assert (done.returncode, done.stdout, done.stderr) == (0, "done 2 0\n", "")
    assert not [p for p in tmp.iterdir() if p.name.startswith("pbdyn-pool-")]   # the pool leaves nothing behind


def test_generate_maps_without_the_main_guard_fails_with_one_line(tmp_path):
    call = ("generate_maps(None, metric='density', target=0.05, tolerance=0.01, count=1, workers=2, "
            "fixed={'count': 10, 'radius': 1.0})")
    script = tmp_path / "unguarded_generate.py"
    script.write_text(UNGUARDED.format(call=call))
    done = _python(str(script), cwd=tmp_path, timeout=120)
    lines = done.stderr.splitlines()
    assert done.returncode != 0 and len(lines) == 1, (done.returncode, done.stderr)
    assert lines[0].startswith("pbdyn: error: generate_maps: was called at the top level of "), lines


def test_the_main_guard_error_is_a_config_error():
    from pbdyn.errors import ConfigError
    from pbdyn.experiments.mainguard import MainGuardError, check_not_reimported, reimporting_main

    err = MainGuardError("run_batch", "/x/script.py")
    assert isinstance(err, ConfigError) and isinstance(err, ValueError) and err.field == "run_batch"
    assert err.code == f"pbdyn: error: {err}" and "\n" not in str(err)
    assert not reimporting_main()
    check_not_reimported("run_batch")            # in the main process: nothing
