"""The agent side of a trial (docs/design.md "One trial step" (4)-(6)): the planner pair, braking and the plan contract.

Each step the agent asks its trajectory planner whether to replan and for a plan, checks every returned plan against
the plan contract (pbdyn.sim.contract) before it can be executed, asks its gaze planner for a yaw rate, and turns
the plan in execution (or braking) into the MAV's state at t_k+1.
"""

from __future__ import annotations

import inspect
import math
import time
from dataclasses import dataclass

import numpy as np

from pbdyn.errors import ConfigError, one_line, user_location
from pbdyn.world.maps import PROGRAM_PX_PER_M
from pbdyn.planning.protocols import PlannerContext
from pbdyn.planning.registry import build_planner, resolve_gaze_planner, resolve_trajectory_planner
from pbdyn.planning.trajectory import Trajectory
from pbdyn.planning.view import MAVLimits, View
from pbdyn.sim.contract import PlanViolation, check_plan, plan_violations
from pbdyn.sim.guard import Action
from pbdyn.sim.state import vector_norm
from pbdyn.sim.spec import TrialSpec
from pbdyn import usercode
from pbdyn.usercode import UserCodeTimeout, quiet_user_code, time_budget, user_stdout


def brake(p: np.ndarray, v: np.ndarray, a_max: float, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One braking step: v -= min(a_max dt, |v|) v/|v|; p advances with the mean velocity (exact for constant a)."""
    speed = vector_norm(v)
    if speed <= 0.0:
        return p.copy(), np.zeros_like(v), np.zeros_like(v)
    dv = min(a_max * dt, speed)
    v1 = v - dv * v / speed
    return p + 0.5 * (v + v1) * dt, v1, (v1 - v) / dt


def program_brake(p: np.ndarray, v: np.ndarray, a: np.ndarray, a_max: float,
                  dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One braking step of the thesis program (its Drone2D.brake): if |v| <= a_max dt the MAV stops where it is,
    else v -= a_max dt v/|v| and p += v_new dt; the acceleration keeps its last value (the next primitive starts
    from it)."""
    speed = vector_norm(v)
    if speed <= a_max * dt:
        return p.copy(), np.zeros_like(v), a.copy()
    v1 = v - (a_max * dt / speed) * v
    return p + v1 * dt, v1, a.copy()


def _project(x: np.ndarray, limit: float) -> np.ndarray:
    n = vector_norm(x)
    return x * (limit / n) if n > limit else x


def planner_context(spec: TrialSpec, physical: bool | None = None) -> PlannerContext:
    """The fixed facts a trial's planners are constructed with (``physical``: the execution rules, default the
    scenario's profile)."""
    sc = spec.scenario
    limits = MAVLimits(sc.drone.radius, spec.v_max, sc.drone.a_max, sc.drone.yaw_rate_limit)
    return PlannerContext(sc.world.dims, sc.world.dt, limits, np.zeros(sc.world.dims),
                          np.asarray(sc.world.size, dtype=float), spec.seed,
                          sc.physical if physical is None else bool(physical))


def profile_params(cls: type, params: dict, physical: bool) -> dict:
    """A planner's parameters under the profile: under thesis_program a built-in class's PROGRAM_PARAMS (the
    thesis program's values) fill in what the scenario's table omits; under physical the table as it is."""
    program = getattr(cls, "PROGRAM_PARAMS", None) if not physical and cls.__module__.startswith("pbdyn.") else None
    return {**program, **params} if program else params


def build_planners(spec: TrialSpec, trajectory=None, gaze=None, physical: bool | None = None):
    """(context, trajectory planner, gaze planner) of a trial. ``trajectory``/``gaze``: a planner class (built
    with the context and the entry's params) or an instance (used as it is) instead of the spec's named ones.
    Under the thesis_program rules (``physical`` False; default: the scenario's profile) built-in planners get
    their PROGRAM_PARAMS (profile_params). Plug-ins' prints while they are built go to stderr (quiet_user_code).
    Trials and pbdyn.experiments.runner.check_planners build planners here."""
    ctx = planner_context(spec, physical)
    idx = next((i for i, e in enumerate(spec.scenario.planners) if e == spec.planner), 0)
    objs = []
    with quiet_user_code():  # Python and C level
        for kind, given, name, params, resolve in (
                ("trajectory", trajectory, spec.planner.trajectory, spec.planner.trajectory_params,
                 resolve_trajectory_planner),
                ("gaze", gaze, spec.planner.gaze, spec.planner.gaze_params, resolve_gaze_planner)):
            if given is not None and not inspect.isclass(given):
                objs.append(given)
                continue
            cls = given if given is not None else resolve(name, f"planners[{idx}].{kind}")
            objs.append(build_planner(cls, ctx, profile_params(cls, dict(params), ctx.physical),
                                      f"planners[{idx}].{kind}_params"))
    return ctx, objs[0], objs[1]


@dataclass
class Decision:
    """The agent's step: the action handed to the environment, and what happened on the way.

    planned: replan_check asked for a plan; plan_ok: False if that plan failed (None); violation: the plan broke
    the contract (the trial must end as invalid_plan; ``action`` is then None); planning_wall_s, gaze_wall_s: wall
    times of steps (4) and (5) (s).
    """

    action: Action | None
    planned: bool
    plan_ok: bool
    violation: PlanViolation | None
    planning_wall_s: float
    gaze_wall_s: float


class Agent:
    """A trial's decision maker: its trajectory and gaze planners, the plan contract, braking and the MAV's
    planning state ("PLANNING" or "EXECUTING"). ``physical`` (default: the scenario's profile): True enforces the
    MAV's limits on every plan and on the executed state; False (thesis_program) checks only a plan's form and
    continuity and executes its samples as the thesis' program did: the position rounded to its 0.1 m pixels,
    velocity and acceleration as planned; and it brakes as the program did (program_brake). The same switch builds
    its planners under those rules (planner_context, profile_params) and, in a TrialBatch, sets the rules the guard
    executes its trial by. ``violations``: every broken check of the plan that ended the trial (empty while plans
    are valid)."""

    def __init__(self, spec: TrialSpec, trajectory=None, gaze=None, *, physical: bool | None = None):
        self.spec = spec
        self.physical = spec.scenario.physical if physical is None else bool(physical)
        self.context, self.planner, self.gaze = build_planners(spec, trajectory, gaze, self.physical)
        self.limits = self.context.limits
        self._plugin = any(not type(x).__module__.startswith("pbdyn.") for x in (self.planner, self.gaze))
        self.fov_deg = getattr(self.gaze, "fov_deg", None)
        self.trajectory: Trajectory | None = None
        self.state = "PLANNING"
        self.consecutive_failures = 0
        self.total_failures = 0
        self.violations: list[PlanViolation] = []

    def act(self, view: View) -> Decision:
        """Steps (4)-(6) at view.t: replan if asked (checking the plan contract), the gaze yaw rate, and the MAV's
        next state from the plan in execution or, without one, a braking step. What the planners print goes to
        stderr (Python-level writes; pbdyn.usercode.user_stdout). A planner's exit or other BaseException
        (SystemExit, GeneratorExit; not KeyboardInterrupt), and any exception of a plug-in pair, becomes a ConfigError
        naming the pair, the time and the file:line in the user's code that raised (pbdyn.errors.user_location), so
        it ends only this trial (a batch's "error" row; ``pbdyn run``: exit 2, one line); a built-in pair's
        exceptions keep their type and traceback (pbdyn's own bug). A pair with a plug-in decides within
        pbdyn.usercode.PLANNER_CALL_TIMEOUT_S of wall-clock time, else the same error names the budget."""
        with user_stdout():
            try:
                if not self._plugin:     # a plug-in's decision gets a wall-clock budget; built-ins pay nothing
                    return self._act(view)
                wd = usercode.watchdog()
                if wd is None:           # outside fly()'s watchdog: a timer of its own
                    with time_budget(usercode.PLANNER_CALL_TIMEOUT_S):
                        return self._act(view)
                wd.started = time.monotonic()
                try:
                    return self._act(view)
                finally:
                    wd.started = None
            except KeyboardInterrupt:
                raise
            except UserCodeTimeout as exc:
                raise self._timeout_error(exc, view.t) from None
            except Exception as exc:
                if not self._plugin:   # a built-in planner's failure is pbdyn's own bug: keep it as it is
                    raise
                raise self._user_error("plug-in planner pair", exc, view.t) from exc
            except BaseException as exc:
                raise self._user_error("planner pair", exc, view.t) from exc

    @property
    def plugin(self) -> bool:
        """True if the trajectory or the gaze planner is a plug-in (not pbdyn's own): its decisions are budgeted
        (pbdyn.usercode.PLANNER_CALL_TIMEOUT_S)."""
        return self._plugin

    def _timeout_error(self, exc: UserCodeTimeout, t: float) -> ConfigError:
        """The ConfigError of a plug-in pair's decision that ran past its budget (PLANNER_CALL_TIMEOUT_S), naming
        the budget and where the user's code was when it was interrupted."""
        entry = self.spec.planner
        where = user_location(exc)
        err = ConfigError("planner", f"the plug-in planner pair {entry.trajectory} + {entry.gaze} did not return "
                          f"within its time budget of {exc.seconds:g} s per decision (PLANNER_CALL_TIMEOUT_S, "
                          f"pbdyn.usercode) at t = {t:g} s" + (f" (at {where})" if where else ""), None,
                          show_value=False)
        err.location = where
        return err

    def _user_error(self, what: str, exc: BaseException, t: float) -> ConfigError:
        """The ConfigError of a planner call that raised ``exc`` at time ``t``: it names the pair, the exception and
        where the user's code raised it (``location``: "file:line", None if not in user code)."""
        entry = self.spec.planner
        where = user_location(exc)
        err = ConfigError("planner", f"the {what} {entry.trajectory} + {entry.gaze} raised {one_line(exc)} at "
                          f"t = {t:g} s" + (f" (at {where})" if where else ""), None, show_value=False)
        err.location = where
        return err

    def _act(self, view: View) -> Decision:
        c3 = time.perf_counter()
        limits = self.limits
        plan_ok = True
        planned = bool(self.planner.replan_check(view))
        if planned:                                                   # (4)
            self.state = "PLANNING"
            new = self.planner.plan(view)
            if new is None:
                self.trajectory = None
                self.consecutive_failures += 1
                self.total_failures += 1
                plan_ok = False
            else:
                bad = check_plan(new, t=view.t, dt=view.dt, position=view.position, velocity=view.velocity,
                                 v_max=limits.v_max, a_max=limits.a_max, physical=self.physical)
                if bad is not None:
                    self.violations = plan_violations(new, t=view.t, dt=view.dt, position=view.position,
                                                      velocity=view.velocity, v_max=limits.v_max,
                                                      a_max=limits.a_max, physical=self.physical)
                    self.trajectory = None
                    return Decision(None, planned, False, bad, time.perf_counter() - c3, 0.0)
                self.trajectory = new
                self.consecutive_failures = 0
                self.state = "EXECUTING"
        c4 = time.perf_counter()
        rate = float(self.gaze.yaw_rate(view, self.trajectory))      # (5)
        if not math.isfinite(rate):
            raise ValueError(f"gaze planner {self.spec.planner.gaze} returned a non-finite yaw rate")
        rate = min(max(rate, -limits.yaw_rate), limits.yaw_rate)
        c5 = time.perf_counter()
        t1 = view.t + view.dt                                         # (6)
        traj = self.trajectory
        if traj is not None and traj.covers(t1) and traj.index_at(t1) >= 1:
            p1, v1, a1 = traj.state_at(t1)
            p1, v1, a1 = p1.astype(float), v1.astype(float), a1.astype(float)   # copies: the plan stays as it was
            if self.physical:
                v1 = _project(v1, limits.v_max)
                a1 = _project(a1, limits.a_max)
            else:
                p1 = np.round(p1 * PROGRAM_PX_PER_M) / PROGRAM_PX_PER_M
        else:
            if traj is not None:
                self.trajectory = None
                self.state = "PLANNING"
            if self.physical:
                p1, v1, a1 = brake(view.position, view.velocity, limits.a_max, view.dt)
            else:
                p1, v1, a1 = program_brake(view.position, view.velocity, view.acceleration, limits.a_max, view.dt)
        action = Action(p1, v1, a1, rate, self.consecutive_failures)
        return Decision(action, planned, plan_ok, None, c4 - c3, c5 - c4)
