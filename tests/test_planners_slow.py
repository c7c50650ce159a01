"""The planners' success rates on the thesis' easiest controlled setup (issue 5), flown through the batch runner.

Setup 10 obstacles of 0.5 m (+-0.2 m) at 2 m/s, v_max 4 m/s, FullRange gaze, 5 maps x 72 start/goal pairs per
planner: local primitives must succeed in >= 85% of the trials, MPC and global primitives in >= 60%, and each must
beat straight_line. Slow (about 1500 trials): run with `pytest -m slow`.
"""

from __future__ import annotations

import pytest

from pbdyn.config import parse_scenario
from pbdyn.experiments.runner import BatchOptions, run_batch
from pbdyn.experiments.store import ResultsStore

PLANNERS = ("local_primitives", "global_primitives", "mpc", "straight_line")
FLOOR = {"local_primitives": 0.85, "global_primitives": 0.60, "mpc": 0.60}


@pytest.mark.slow
def test_success_rates_on_the_easy_setup(tmp_path):
    sc = parse_scenario({"name": "easy", "obstacles": {"count": 10, "radius": 0.5, "speed": 2.0,
                                                       "radius_jitter": 0.2, "maps_per_setup": 5},
                         "drone": {"v_max": 4.0},
                         "planners": [{"trajectory": t, "gaze": "fullrange"} for t in PLANNERS]})
    out = tmp_path / "easy.sqlite"
    summary = run_batch(sc, out, BatchOptions(workers=2, metrics=False, progress=False))
    assert summary.total == 5 * 72 * len(PLANNERS) and summary.errors == 0
    store = ResultsStore.open(out)
    rows = store.results()
    store.close()
    rate = {}
    for t in PLANNERS:
        mine = [r for r in rows if r["planner"] == t]
        assert len(mine) == 360
        rate[t] = sum(r["outcome"] == "success" for r in mine) / len(mine)
    print("success rates (n = 360 each):", rate)
    for t, floor in FLOOR.items():
        assert rate[t] >= floor, (t, rate)
        assert rate[t] > rate["straight_line"], (t, rate)
