"""Fuzzing pbdyn's files and arguments (tests/fuzz_io.py): crafted traces for `pbdyn replay`, output paths of every
command that writes one, `pbdyn merge` inputs, and the Python API's parameters. Oracle: fuzz_io.verdict (exit 0
with the output, or exit 2 with one line and nothing written; the API returns or raises a pbdyn error naming the
parameter). A failure names its case; reproduce it with ``python -m tests.fuzz_io CLASS INDEX``.

Default run: N_DEFAULT cases of each class; ``-m slow``: N_SLOW more of each."""

from __future__ import annotations

import shutil
import sys

import pytest

from tests.fuzz_io import CLASSES, make, make_assets, run_case, verdict

N_DEFAULT = {"trace": 40, "outpath": 11, "merge": 30, "api": 40}
N_SLOW = 300
TIME_BOUND_S = 60.0

pytestmark = pytest.mark.fuzz


@pytest.fixture(scope="module")
def assets(tmp_path_factory):
    return make_assets(tmp_path_factory.mktemp("fuzzio") / "assets")


def _fuzz(kind: str, indices, assets, tmp_path, capsys) -> None:
    failures = []
    for i in indices:
        case, data = make(kind, i, assets)
        folder = tmp_path / f"{kind}{i}"
        out = run_case(case, folder, assets, timeout_s=TIME_BOUND_S, data=data)
        problem = verdict(case, out, TIME_BOUND_S)
        if problem:
            failures.append(f"{case.describe()}\n    -> {problem}\n    reproduce: python -m tests.fuzz_io {kind} {i}")
        shutil.rmtree(folder, ignore_errors=True)
    with capsys.disabled():
        sys.stdout.write(f"\nfuzz-io {kind}: {len(indices)} cases, {len(failures)} failed\n")
    assert not failures, f"{len(failures)} {kind} cases broke the contract:\n" + "\n".join(failures)


@pytest.mark.parametrize("kind", CLASSES)
def test_fuzz_io(kind, assets, tmp_path, capsys):
    _fuzz(kind, range(N_DEFAULT[kind]), assets, tmp_path, capsys)


@pytest.mark.slow
@pytest.mark.parametrize("kind", CLASSES)
def test_fuzz_io_many(kind, assets, tmp_path, capsys):
    _fuzz(kind, range(N_DEFAULT[kind], N_DEFAULT[kind] + N_SLOW), assets, tmp_path, capsys)


def test_fuzz_io_cases_are_deterministic(assets):
    for kind in CLASSES:
        for i in (0, 7):
            (a, da), (b, db) = make(kind, i, assets), make(kind, i, assets)
            assert a.describe() == b.describe() and a.argv == b.argv and da == db
