"""The trial core flies every recorded case exactly as before (tests/core_fixture.py, tests/data/core_rows.json.gz):
rows (wall times and the planner fingerprint aside) and trace arrays bit-identical, one by one and in batches."""

from __future__ import annotations

import gzip
import json
import tempfile
from pathlib import Path

import pytest

from tests import core_fixture as fx


@pytest.fixture(scope="module")
def recorded() -> dict:
    return json.loads(gzip.decompress(fx.FIXTURE.read_bytes()))


def _first_difference(got: dict, want: dict) -> str:
    keys = sorted(k for k in set(got) | set(want) if got.get(k, "<missing>") != want.get(k, "<missing>"))
    return ", ".join(f"{k}: {got.get(k, '<missing>')!r} != {want.get(k, '<missing>')!r}" for k in keys[:4])


def test_a_batch_of_72_flies_the_recorded_rows(recorded):
    got = fx.fly_batch("batch_72")
    want = recorded["batch_72"]["batch"]
    assert len(got) == len(want) == 72
    bad = [i for i, (g, w) in enumerate(zip(got, want)) if g != w]
    assert not bad, f"{len(bad)} rows differ; first: case {bad[0]}: {_first_difference(got[bad[0]], want[bad[0]])}"


def test_single_trials_fly_the_recorded_rows_and_traces(recorded):
    """Every traced case and every 6th case of each group (thesis_program: every 18th), flown one by one."""
    from pbdyn.sim.trial import run_trial

    checked = 0
    with tempfile.TemporaryDirectory() as tmp:
        for name in fx.groups():
            if name == "batch_72":
                continue
            _, ro, specs = fx.specs_of(name)
            every = 18 if name == "thesis_program" else 6
            for i, spec in enumerate(specs):
                traced = (name, i) in fx.TRACED
                if i % every and not traced:
                    continue
                trace = Path(tmp, f"{name}{i}.npz") if traced else None
                row = fx.row_of(run_trial(spec, ro, trace_path=trace))
                want = recorded[name]["rows"][i]
                assert row == want, f"{name} case {i}: {_first_difference(row, want)}"
                if traced:
                    assert fx.trace_digest(trace) == recorded[name]["traces"][str(i)], f"{name} case {i}: trace"
                checked += 1
    assert checked >= 25


@pytest.mark.slow
def test_every_recorded_case_flies_the_same_one_by_one_and_in_batches(recorded):
    for name in fx.groups():
        got = fx.fly_one_by_one(name)
        assert got["rows"] == recorded[name]["rows"], name
        assert got["traces"] == recorded[name]["traces"], name
        assert fx.fly_batch(name) == recorded[name]["batch"], name
