"""Shared test fixtures: an isolated rollout cache per test session and scenario-writing helpers."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SCENARIOS = ROOT / "scenarios"


@pytest.fixture(autouse=True, scope="session")
def _isolated_cache(tmp_path_factory):
    cache = tmp_path_factory.mktemp("pbdyn-cache")
    old = os.environ.get("PBDYN_CACHE")
    os.environ["PBDYN_CACHE"] = str(cache)
    yield cache
    if old is None:
        os.environ.pop("PBDYN_CACHE", None)
    else:
        os.environ["PBDYN_CACHE"] = old


@pytest.fixture
def write_scenario(tmp_path):
    """Write TOML text to a file in tmp_path and return its path."""
    def _write(text: str, name: str = "scenario.toml") -> Path:
        p = tmp_path / name
        p.write_text(text)
        return p
    return _write


def pbdyn_cmd() -> list[str]:
    """The command line that runs the pbdyn CLI with this interpreter."""
    return [sys.executable, "-m", "pbdyn.cli"]


def pytest_configure(config):
    config.addinivalue_line("markers", "fuzz: the CLI-contract fuzz tests (tests/test_fuzz.py); run them alone with "
                                       "-m 'fuzz and not slow', or all of them with -m fuzz")
