"""The plan contract: unit checks, cheating planners end as invalid_plan, check_planner, built-ins never breach."""

from __future__ import annotations

import numpy as np
import pytest

from pbdyn.planning.trajectory import Trajectory
from pbdyn.sim.checker import check_planner
from pbdyn.sim.contract import CHECKS, check_plan, plan_violations
from tests import cheating_planners as cheats
from tests.helpers import first_map, handmade_rollout, open_scenario

DT, VMAX, AMAX = 0.1, 4.0, 4.0


def _violations(p, v, a, *, t0=0.0, dt=DT, pos=None, vel=None, **kw):
    traj = Trajectory(t0, dt, np.asarray(p, float), np.asarray(v, float), np.asarray(a, float))
    pos = traj.p[0] if pos is None else pos
    vel = traj.v[0] if vel is None else vel
    return [x.check for x in plan_violations(traj, t=0.0, dt=DT, position=pos, velocity=vel, v_max=VMAX,
                                              a_max=AMAX, **kw)]


def test_position_step_bound_is_exact():
    """+a_max for half a step then -a_max reaches p0 + a_max dt^2 / 4 at unchanged velocity: allowed; 0.1% more is not."""
    d = AMAX * DT * DT / 4.0
    v0 = [1.0, 0.0]
    ok = [[0.0, 0.0], [0.1 + d, 0.0]]
    assert _violations(ok, [v0, v0], np.zeros((2, 2))) == []
    assert _violations([[0.0, 0.0], [0.1 + 1.001 * d, 0.0]], [v0, v0], np.zeros((2, 2))) == ["position_step"]
    diagonal = [[0.0, 0.0], [0.1 + d / np.sqrt(2) * 1.0000001, d / np.sqrt(2) * 1.0000001]]
    assert _violations(diagonal, [v0, v0], np.zeros((2, 2))) == ["position_step"]


def test_each_check_fires_alone():
    z = np.zeros((3, 2))
    line_v = np.array([[0.0, 0.0], [0.4, 0.0], [0.8, 0.0]])           # a = 4 m/s^2 exactly
    line_p = np.array([[0.0, 0.0], [0.02, 0.0], [0.08, 0.0]])
    line_a = np.array([[4.0, 0.0]] * 3)
    assert _violations(line_p, line_v, line_a) == []
    assert _violations(line_p, line_v * 1.01, line_a) == ["velocity_step"]
    assert _violations(line_p, line_v, line_a * 1.01) == ["acceleration"]
    fast = np.array([[4.1, 0.0]] * 3)
    assert _violations(line_p * 0 + [[0, 0], [0.41, 0], [0.82, 0]], fast, z) == ["speed"]
    assert _violations(line_p, line_v, line_a, t0=0.1) == ["t0"]
    assert _violations(line_p, line_v, line_a, dt=0.05) == ["dt", "velocity_step", "position_step"]
    assert _violations(line_p, line_v, line_a, pos=np.array([0.0, 2e-6])) == ["start_position"]
    assert _violations(line_p, line_v, line_a, vel=np.array([2e-6, 0.0])) == ["start_velocity"]
    assert _violations(line_p, line_v, line_a, pos=np.array([0.0, 5e-7])) == []
    assert _violations(line_p * 1.0, line_v, line_a, physical=False) == []
    assert _violations(line_p, line_v * 3, line_a * 3, physical=False) == []
    nan = line_p.copy()
    nan[2, 1] = np.nan
    assert _violations(nan, line_v, line_a) == ["finite"]
    assert _violations(line_p[:1], line_v[:1], line_a[:1]) == ["shape"]
    assert set(CHECKS) >= {"type", "shape", "finite", "t0", "dt", "start_position", "start_velocity", "speed",
                           "acceleration", "velocity_step", "position_step"}


@pytest.mark.parametrize("physical", [True, False])
def test_check_plan_decides_as_plan_violations_at_the_bounds(physical):
    """check_plan's fast screen passes no plan that plan_violations refuses: plans on and just around every bound
    (speed, acceleration, velocity step, position gap, start state), in 2D and 3D, including NaN and inf."""
    rng = np.random.default_rng(8)
    factors = (0.5, 1.0 - 1e-12, 1.0, 1.0 + 1e-12, 1.0 + 5e-10, 1.0 + 2e-9, 1.5)
    refused = passed = 0
    for it in range(1500):
        d = 2 + it % 2
        k = int(rng.integers(2, 9))
        u = rng.normal(size=d)
        u /= np.linalg.norm(u)
        speed = VMAX * rng.choice(factors)
        v = np.tile(u * speed, (k, 1))
        a = np.tile(rng.normal(size=d), (k, 1))
        a *= AMAX * rng.choice(factors) / np.linalg.norm(a[0])
        p = np.cumsum(np.vstack([np.zeros(d), np.tile(u * speed * DT, (k - 1, 1))]), axis=0)
        j = int(rng.integers(1, k))
        kind = it % 5
        if kind == 1:                      # a velocity step at the bound a_max dt
            w = rng.normal(size=d)
            v[j:] += w / np.linalg.norm(w) * AMAX * DT * rng.choice(factors)
            p[j:] += 0.5 * (v[j] - v[j - 1]) * DT
        elif kind == 2:                    # a position gap at the bound a_max dt^2 / 4
            w = rng.normal(size=d)
            p[j:] += w / np.linalg.norm(w) * AMAX * DT * DT / 4.0 * rng.choice(factors)
        elif kind == 3:                    # the start state off by the tolerance
            p += rng.choice([0.0, 1e-6, 1e-6 * (1 + 1e-9)]) * np.eye(d)[0]
        elif kind == 4 and it % 3 == 0:
            p[j, 0] = rng.choice([np.nan, np.inf])
        traj = Trajectory(0.0, DT, p, v, a)
        kw = dict(t=0.0, dt=DT, position=p[0] * 0.0 if kind == 3 else p[0], velocity=v[0], v_max=VMAX,
                  a_max=AMAX, physical=physical)
        want = plan_violations(traj, first_only=True, **kw)
        got = check_plan(traj, **kw)
        assert got == (want[0] if want else None), it
        refused += got is not None
        passed += got is None
    assert refused > (100 if physical else 30) and passed > 100


def _fly_cheat(cls, dims=2, **kw):
    from dataclasses import replace

    from pbdyn.config import PlannerEntry
    from pbdyn.sim.trial import make_trial_spec, run_trial

    sc = open_scenario(dims)
    z = [10.0] if dims == 3 else []
    ro = handmade_rollout(sc, np.zeros((0, dims)), np.zeros((0, dims)), [])
    spec = make_trial_spec(sc, first_map(sc), start=tuple([4.0, 25.0] + z), goal=tuple([46.0, 25.0] + z))
    spec = replace(spec, planner=PlannerEntry(f"tests.cheating_planners:{cls.__name__}", "lookahead"))
    return run_trial(spec, ro, trajectory_planner=cls, **kw)


@pytest.mark.parametrize("cls, check, sample", [(cheats.OverSpeed, "speed", 1), (cheats.Teleport, "position_step", 1),
                                                (cheats.WrongT0, "t0", None), (cheats.StartOff, "start_position", 0),
                                                (cheats.NotATrajectory, "type", None)])
@pytest.mark.parametrize("dims", [2, 3])
def test_cheating_planner_ends_invalid_plan(tmp_path, cls, check, sample, dims):
    trace = tmp_path / "t.npz"
    res = _fly_cheat(cls, dims, trace_path=trace)
    assert res.outcome == "invalid_plan"
    assert f"plan broke {check}" in res.reason
    if sample is not None:
        assert f"at sample {sample}" in res.reason
    assert res.flight_time_s == 0.0 and res.steps == 0
    with np.load(trace) as z:
        assert z["p"].shape[0] == 0 and str(z["outcome"]) == "invalid_plan"
        assert np.allclose(z["final_p"], [4.0, 25.0] + ([10.0] if dims == 3 else []))


def test_late_cheat_never_executes_the_bad_plan(tmp_path):
    trace = tmp_path / "t.npz"
    res = _fly_cheat(cheats.LateCheat, trace_path=trace)
    assert res.outcome == "invalid_plan" and "position_step at sample 1" in res.reason
    assert res.flight_time_s == pytest.approx(0.5) and res.steps == 5
    with np.load(trace) as z:
        assert z["p"].shape[0] == 5
        assert np.linalg.norm(z["final_v"]) <= 1.0 + 1e-9          # 0.5 s at 2 m/s^2
        assert z["final_p"][0] - 4.0 == pytest.approx(0.5 * 2.0 * 0.5 ** 2)


def test_check_planner_reports_cheats_and_passes_builtins():
    sc = open_scenario(2)
    bad = check_planner(cheats.OverSpeed, sc, maps=1, pairs=3)
    assert not bad.ok and bad.trials == 3 and bad.outcomes == {"invalid_plan": 3}
    assert all(b.violations[0].check == "speed" for b in bad.breaches)
    assert {v.check for v in bad.breaches[0].violations} == {"speed", "velocity_step", "position_step"}
    assert "invalid plans" in str(bad) and "plan broke speed" in str(bad)
    named = check_planner("tests.cheating_planners:Teleport", sc, maps=1, pairs=2)
    assert named.planner == "tests.cheating_planners:Teleport" and named.outcomes == {"invalid_plan": 2}
    good = check_planner("local_primitives", sc, maps=1, pairs=2)
    assert good.ok and good.outcomes == {"success": 2} and "respected" in str(good)


def _dataset(name: str, time_limit: float):
    import tomllib

    from pbdyn.config import parse_scenario
    from tests.conftest import SCENARIOS

    doc = tomllib.loads((SCENARIOS / "datasets" / f"{name}.toml").read_text())
    doc["world"]["time_limit"] = time_limit
    return parse_scenario(doc)


TRAJECTORY = ("local_primitives", "global_primitives", "mpc", "straight_line", "local_primitives_minjerk")
GAZES = ("lookahead", "fullrange", "finean")
MAPS = list(range(0, 540, 27))     # 20 maps over every (count, radius, speed) setup of the controlled datasets


def _assert_no_breach(scenario, trajectory, gazes, v_max, maps=MAPS):
    for k, gaze in enumerate(gazes):
        chosen = maps if len(gazes) == 1 or len(maps) == len(MAPS) else maps[k::len(gazes)]
        rep = check_planner(trajectory, scenario, maps=chosen, pairs=1, gaze=gaze, v_max=v_max)
        assert rep.ok, str(rep)
        assert rep.trials == len(chosen)


@pytest.mark.parametrize("trajectory", TRAJECTORY)
def test_builtins_never_breach_2d(trajectory):
    """Every built-in trajectory planner on 20 2D maps at 6 m/s, the 3 gaze planners taking turns (first 10 s of
    each trial; every gaze on every map: the slow test)."""
    sc = _dataset("controlled_2d", 10.0)
    for k, gaze in enumerate(GAZES):
        rep = check_planner(trajectory, sc, maps=MAPS[k::3], pairs=1, gaze=gaze, v_max=6.0)
        assert rep.ok and rep.trials == len(MAPS[k::3]), str(rep)


@pytest.mark.parametrize("trajectory", TRAJECTORY)
def test_builtins_never_breach_3d(trajectory):
    """Every built-in trajectory planner on 20 3D maps, the 3 gaze planners taking turns (first 6 s of each)."""
    sc = _dataset("controlled_3d", 6.0)
    for k, gaze in enumerate(GAZES):
        rep = check_planner(trajectory, sc, maps=MAPS[k::3], pairs=1, gaze=gaze, v_max=4.0)
        assert rep.ok, str(rep)


@pytest.mark.slow
@pytest.mark.parametrize("dims", [2, 3])
@pytest.mark.parametrize("trajectory", TRAJECTORY)
def test_builtins_never_breach_full(trajectory, dims):
    """The full check: every built-in x 3 gaze planners x 20 maps x 3 MAV speeds, whole trials (80 s)."""
    sc = _dataset(f"controlled_{dims}d", 80.0)
    for v in (2.0, 4.0, 6.0):
        _assert_no_breach(sc, trajectory, GAZES, v)


class _Raises:
    def __init__(self, context, **params):
        pass

    def replan_check(self, view):
        return True

    def plan(self, view):
        raise ZeroDivisionError("the plug-in divided by zero")


def test_a_plugin_that_raises_ends_with_one_line_naming_it():
    """A plug-in's exception in plan() is the plug-in's bug: a ConfigError naming the pair and the time (CLI exit 2,
    batch error row), not pbdyn's internal error."""
    import pbdyn

    with pytest.raises(pbdyn.ConfigError) as err:
        pbdyn.run_trial("quickstart", planner=_Raises)
    text = str(err.value)
    assert "plug-in planner pair" in text and "ZeroDivisionError" in text and "t = 0 s" in text and "\n" not in text
