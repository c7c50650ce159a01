"""Refactors keep behaviour: built-in planner trials fly bit-identically to the recorded fixture rows."""

from __future__ import annotations

import json

from tests.trial_fixture import FIXTURE, cases, fly_cases


def test_fixture_rows_are_bit_identical():
    recorded = json.loads(FIXTURE.read_text())
    assert [r["case"] for r in recorded] == [[n, m, t, g, list(s), list(e)] for n, m, t, g, s, e in cases()]
    now = fly_cases()
    assert len(now) == len(recorded) >= 48
    for old, new in zip(recorded, now):
        assert json.loads(json.dumps(new["row"], sort_keys=True)) == old["row"], old["case"]
