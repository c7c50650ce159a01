"""Task-level metrics (pbdyn.metrics.task) by hand on a one-obstacle map, their samples, imported bodies, and the
trial rows that carry them."""

from __future__ import annotations

import numpy as np
import pytest

from pbdyn.metrics.task import corridor_flux, corridor_points, corridor_survivability, equivalent_radii
from pbdyn.world.geometry import StaticBody
from tests.test_baselines import SPHERE
from tests.test_metrics import make_rollout
from tests.test_worlds import rollout_of, world

START, GOAL = (4.0, 25.0), (46.0, 25.0)


def test_corridor_samples_along_and_beside_the_segment():
    pts = corridor_points(START, GOAL, np.array([50.0, 50.0]))
    xs = 4.0 + 3.0 * np.arange(15)                       # 42 m in 3 m steps: 15 points per line
    want = np.concatenate([np.stack([xs, np.full(15, y)], 1) for y in (25.0, 28.0, 22.0)])
    np.testing.assert_allclose(pts, want, atol=1e-12)
    # near a wall the side line outside the arena (MAV disc beyond the wall) is dropped
    edge = corridor_points((4.0, 2.0), (46.0, 2.0), np.array([50.0, 50.0]))
    assert set(np.round(edge[:, 1], 9)) == {2.0, 5.0}
    # 3D: the line and four shifted copies across it
    p3 = corridor_points((4.0, 4.0, 10.0), (46.0, 46.0, 10.0), np.array([50.0, 50.0, 20.0]))
    assert p3.shape[0] == 5 * (int(np.ceil(np.hypot(42, 42) / 3.0)) + 1)
    assert corridor_points(START, GOAL, np.array([50.0, 50.0]), half_width=0.0).shape == (15, 2)


def _one_obstacle(static=()):
    # radius 1 at (25, 35) heading -y at 2 m/s: it crosses the corridor's x = 25 column only
    return make_rollout([[25.0, 35.0]], [[0.0, -2.0]], [1.0], static=static)


def test_corridor_survivability_and_flux_by_hand():
    ro = _one_obstacle()
    surv, n = corridor_survivability(ro, START, GOAL)
    # samples (25, 28), (25, 25), (25, 22) are reached when 35 - 2 t - y < 2, first step after t = (33 - y) / 2
    hit = [2.6, 4.1, 5.6]
    assert n == 45 and surv == pytest.approx((42 * 12.0 + sum(hit)) / 45, abs=1e-9)
    flux, n2 = corridor_flux(ro, START, GOAL)
    assert n2 == 45 and flux == pytest.approx(3 / (45 * 12.0), rel=1e-12)
    # from t = 5 s the obstacle sits on (25, 25) (hit at once), has left (25, 28) behind, reaches (25, 22) at 0.6 s
    later, _ = corridor_survivability(ro, START, GOAL, start_time=5.0)
    assert later == pytest.approx((43 * 12.0 + 0.0 + 0.6) / 45, abs=1e-9)
    assert corridor_flux(ro, START, GOAL, start_time=5.0)[0] == pytest.approx(2 / (45 * 12.0), rel=1e-12)
    # a short horizon: the path ends before the corridor
    assert corridor_flux(ro, START, GOAL, horizon=2.0)[0] == 0.0
    # an obstacle off the corridor and parallel to it changes nothing
    far = make_rollout([[25.0, 40.0]], [[3.0, 0.0]], [1.0])
    assert corridor_survivability(far, START, GOAL)[0] == 12.0 and corridor_flux(far, START, GOAL)[0] == 0.0


def test_samples_on_static_geometry_are_left_out():
    pillar = (StaticBody("pillar", (10.0, 25.0), radius=1.0),)
    surv, n = corridor_survivability(_one_obstacle(pillar), START, GOAL)
    assert n == 44                                    # the sample at (10, 25) is inside the inflated pillar
    assert surv == pytest.approx((41 * 12.0 + 2.6 + 4.1 + 5.6) / 44, abs=1e-9)
    assert corridor_flux(_one_obstacle(pillar), START, GOAL) == (pytest.approx(3 / (44 * 12.0)), 44)


def test_imported_sphere_sweeps_like_a_generated_disc():
    sc = world([{"name": "ball", "urdf": SPHERE, "position": [25.0, 35.0, 2.0], "motion": "constant_velocity",
                 "velocity": [0.0, -2.0]}])
    ro = rollout_of(sc)
    assert equivalent_radii(ro, 0.0)[0] == pytest.approx(1.0, abs=0.02)
    assert corridor_flux(ro, START, GOAL)[0] == pytest.approx(3 / (45 * 12.0), rel=1e-9)


def test_trial_rows_carry_the_task_metrics_of_their_own_task_and_start():
    from pbdyn.api import rollout, run_trial

    res = run_trial("quickstart", map=4, start=(4.0, 46.0), goal=(46.0, 4.0))
    ro = rollout("quickstart", 4)
    t0 = res.start_delay_s
    surv, _ = corridor_survivability(ro, (4.0, 46.0), (46.0, 4.0), start_time=t0)
    flux, _ = corridor_flux(ro, (4.0, 46.0), (46.0, 4.0), start_time=t0)
    assert res.task_survivability_s == round(surv, 10) and res.task_flux_per_s == round(flux, 12)
    assert 0.0 < res.task_survivability_s <= 12.0 and res.task_flux_per_s >= 0.0
    other = run_trial("quickstart", map=4, start=(4.0, 4.0), goal=(46.0, 46.0))
    assert other.task_survivability_s != res.task_survivability_s


def test_trials_of_one_task_share_its_metrics_once_computed(monkeypatch):
    """task_metrics is computed once per (rollout, task, start time): a second speed of the same task reads the
    memo (the same values as computing afresh), another task or another rollout computes its own."""
    import pbdyn.metrics.task as task_mod
    from pbdyn.config import load_scenario
    from pbdyn.sim import trial
    from pbdyn.world.maps import get_map
    from pbdyn.world.rollout import get_rollout

    sc = load_scenario("quickstart")
    ro = get_rollout(sc, get_map(sc, 4))
    calls = []
    real = task_mod.corridor_survivability
    monkeypatch.setattr(task_mod, "corridor_survivability", lambda *a, **k: calls.append(a[1:3]) or real(*a, **k))
    specs = [trial.make_trial_spec(sc, get_map(sc, 4), v_max=v, start=(4.0, 46.0), goal=(46.0, 4.0))
             for v in (2.0, 3.0)]
    first = trial.task_metrics(specs[0], ro, 1.5)
    assert trial.task_metrics(specs[1], ro, 1.5) == first and len(calls) == 1
    trial._TASK_MEMOS.clear()
    assert trial.task_metrics(specs[1], ro, 1.5) == first and len(calls) == 2          # afresh: the same
    trial.task_metrics(specs[1], ro, 2.5)
    other = trial.make_trial_spec(sc, get_map(sc, 4), start=(4.0, 4.0), goal=(46.0, 46.0))
    trial.task_metrics(other, ro, 1.5)
    trial.task_metrics(specs[0], get_rollout(sc, get_map(sc, 5)), 1.5)
    assert len(calls) == 5
