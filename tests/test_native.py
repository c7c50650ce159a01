"""The native ruckig batch (pbdyn.planning.primitives.native) and the compiled candidate search built on it, against
their references: the ruckig Python package, and the local planner's Python chunk loop, bit for bit."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pbdyn.planning.primitives import native
from pbdyn.planning.primitives.local import LocalPrimitives
from tests.test_planners import _context, _random_views

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    """The loaded native library: the installed one (make builds it), else one built here from ruckig's sources
    (needs a C++ compiler and the package index); skipped, with the reason, when neither is possible."""
    path = native.LIBRARY
    if not path.is_file():
        from pbdyn.planning.primitives.native.build import BuildError, build

        try:
            path = build(output=tmp_path_factory.mktemp("native") / "_ruckig_batch.so")
        except BuildError as exc:
            pytest.skip(f"native ruckig batch not available: {exc}")
    return native._load(path)


@pytest.mark.parametrize("d", [2, 3])
def test_library_builds_what_the_ruckig_package_builds(library, d):
    """Durations, profiles and which inputs are rejected, bit for bit, on 2,000 planner-like inputs (some with
    zero components, some infeasible) and two jerk limits."""
    inputs = native.probe_inputs(d, 1000, seed=7)
    for jerk, min_duration in ((20.0, 0.5), (5.0, 1.8)):
        prof, dur, res = native.build_with_library(library, inputs, jerk, min_duration)
        ref_prof, ref_dur, ref_res = native.build_with_package_reference(inputs, jerk, min_duration)
        ok = (res == 0) | (res == 1)
        assert np.array_equal(ok, ref_res >= 0) and 0 < ok.sum() < len(ok)
        assert np.array_equal(res[ok], ref_res[ok])
        assert np.array_equal(dur[ok], ref_dur[ok]) and np.array_equal(prof[ok], ref_prof[ok])


def test_the_planners_use_the_library_when_it_is_built(library):
    assert native.LIBRARY.is_file() or pytest.skip("the library was built for this test only")
    assert native.ruckig_build_address() is not None
    assert native.status() == "native ruckig batch: in use"
    assert LocalPrimitives(_context()).uses_native


@pytest.mark.parametrize("dims", [2, 3])
def test_compiled_search_chooses_as_the_python_chunk_loop(library, dims):
    """plan() through the native library and the compiled search returns the same trajectory, rank and candidates
    tried as plan() through the ruckig package and the Python chunk loop, with no more ruckig builds, on clear,
    partly blocked and fully blocked views."""
    if native.ruckig_build_address() is None:
        pytest.skip("the planners do not use the library here")
    ctx = _context(dims)
    fast = LocalPrimitives(ctx, sphere_spacing_deg=30.0)
    ref = LocalPrimitives(ctx, sphere_spacing_deg=30.0)
    ref._native = None
    assert fast.uses_native and not ref.uses_native
    seen = {"first": 0, "later": 0, "none": 0}
    for view in _random_views(ctx, np.random.default_rng(17), 150 if dims == 2 else 80):
        got, want = fast.plan(view), ref.plan(view)
        assert (got is None) == (want is None)
        for name in ("last_rank", "last_candidates_tried"):
            assert getattr(fast, name) == getattr(ref, name), name
        assert 0 < fast.last_candidates_built <= ref.last_candidates_built   # no chunk built past the choice
        if want is None:
            seen["none"] += 1
            continue
        for x, y in ((got.p, want.p), (got.v, want.v), (got.a, want.a)):
            assert np.array_equal(x, y)
        assert np.array_equal(fast.last_target, ref.last_target)
        seen["first" if want is not None and fast.last_rank == 0 else "later"] += 1
    assert all(n > 0 for n in seen.values()), seen


def _run_json(extra_env: dict, *args) -> dict:
    env = dict(os.environ, PYTHONHASHSEED="0", **extra_env)
    done = subprocess.run([sys.executable, "-m", "pbdyn.cli", "run", "quickstart", "--json", *args],
                          capture_output=True, text=True, env=env, cwd=ROOT, timeout=300)
    assert done.returncode == 0, done.stderr
    row = json.loads(done.stdout)
    return {k: v for k, v in row.items() if "wall" not in k}


def test_a_trial_flies_the_same_with_and_without_the_library(library):
    """`pbdyn run` in fresh processes, the library on and off (PBDYN_NATIVE=0): the same row."""
    if native.ruckig_build_address() is None:
        pytest.skip("the planners do not use the library here")
    for args in ((), ("--map", "2", "--vmax", "6", "--start", "46,4", "--goal", "4,46")):
        on, off = _run_json({}, *args), _run_json({"PBDYN_NATIVE": "0"}, *args)
        assert on == off and on["outcome"]


def test_switched_off_by_the_environment():
    code = "from pbdyn.planning.primitives import native; print(native.status()); print(native.ruckig_build_address())"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                          env=dict(os.environ, PBDYN_NATIVE="0"))
    assert done.stdout.splitlines() == ["native ruckig batch: off (PBDYN_NATIVE=0)", "None"]


def test_build_tool_says_what_went_wrong_in_one_line(tmp_path):
    """A missing source archive or compiler: exit status 1, one line on stderr, no library written."""
    out = tmp_path / "lib.so"
    cases = [(["--sdist", str(tmp_path / "missing.tar.gz")], {}, "sdist: no such file"),
             ([], {"CXX": str(tmp_path / "no-such-compiler")}, "no-such-compiler was not found")]
    for args, env, words in cases:
        done = subprocess.run([sys.executable, "-m", "pbdyn.planning.primitives.native.build", "--output", str(out),
                               *args],
                              capture_output=True, text=True, env=dict(os.environ, **env), timeout=600)
        lines = [ln for ln in done.stderr.splitlines() if ln.strip()]
        assert done.returncode == 1 and len(lines) == 1 and words in lines[0], done.stderr
        assert lines[0].startswith("pbdyn: native ruckig batch not built") and not out.exists()


@pytest.mark.parametrize("d", [2, 3])
def test_compiled_frame_products_equal_numpys_where_the_planner_uses_them(d):
    """Where the probe lets search() compute the candidates' frame inputs (frame_products_known), they equal
    numpy's products on fresh random frames, states and fan-sized stacks; elsewhere the planner keeps numpy's."""
    from pbdyn.planning.primitives.compiled.candidate_search import (frame_inputs, frame_inputs_reference,
                                                                     frame_products_known)

    planner = LocalPrimitives(_context(d))
    assert planner._counts[3] == int(frame_products_known(d))
    if not frame_products_known(d):
        pytest.skip(f"numpy's {d}D stacked products follow another order here: the planner uses numpy's")
    rng = np.random.default_rng(99)
    for n in (1, 3, 71, 411):
        bases = planner._bases[rng.integers(0, planner.n_candidates, n)]
        state = rng.normal(size=(3, d)) * np.array([[20.0], [4.0], [4.0]])
        targets = state[0] + 3.0 * planner.directions[rng.integers(0, planner.n_candidates, n)]
        vels = rng.normal(size=(n, d))
        got = frame_inputs(bases, targets, vels, state)
        want = frame_inputs_reference(bases, targets, vels, state[0], state[1], state[2])
        for i in range(4):
            assert np.array_equal(got[i], want[i])
