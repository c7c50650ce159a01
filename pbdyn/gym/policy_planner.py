"""A learned policy flown as a planner pair, so that it gets a score card like any planner (docs/gym.md "Scoring a
policy with pbdyn bench").

A policy is a callable ``policy(observation) -> action``: the observation is AvoidEnv's (pbdyn.gym.observation,
float32, world frame; built here from the planner's View by observe_view, with the tracks and occupancy patch AvoidEnv
was given but no depth bins: rays = 0), the action AvoidEnv's Box [-1, 1]^(d+1): action[:d] * a_max is an
acceleration command (m/s^2, world frame), action[d] * the yaw-rate limit the yaw rate (rad/s). E.g. a
Stable-Baselines3 model: ``lambda obs: model.predict(obs, deterministic=True)[0]``.

``PolicyPlanner`` (trajectory planner) asks the policy once per step and turns the action into the next state exactly
as AvoidEnv does (clipped to [-1, 1], then pbdyn.sim.guard.integrate from the view's position and velocity): its plan
is two samples, the view's state and that next state, and always keeps the plan contract (pbdyn/sim/contract.py).
``PolicyGaze`` (gaze planner) returns the yaw rate of the same policy call. Under the physical profile a policy
flies the same trial through them as in AvoidEnv with the same map, task and speed (tests/test_gym_policy.py).

For ``pbdyn bench`` the policy is named as "package.module:factory" in the trajectory planner's parameters (the
factory, defined in a module of your own, not the standard library's nor pbdyn's, is called with ``policy_args`` and
returns the callable); from Python, policy_pair() builds both planners of one callable for pbdyn.run_trial.
"""

from __future__ import annotations

import json
import sys
import threading
from collections.abc import Callable, Mapping

import numpy as np

from pbdyn.errors import ConfigError, import_object, one_line, user_location
from pbdyn.gym.env import command
from pbdyn.gym.observation import check_observed, observe_view
from pbdyn.planning.trajectory import Trajectory
from pbdyn.sim.guard import integrate

Policy = Callable[[np.ndarray], np.ndarray]
"""observation (float32 [n], pbdyn.gym.observation) -> action ([d + 1], in [-1, 1]; AvoidEnv's action)."""

_LOADED: dict[tuple[str, str], Policy] = {}
_LAST = threading.local()       # the last step a PolicyPlanner took in this thread: (view, action)


def load_policy(policy, policy_args: Mapping | None = None) -> Policy:
    """The policy callable of ``policy``: a callable (returned as it is), or "package.module:factory", whose factory
    is called as ``factory(**policy_args)`` once per process for each (name, args) (the callable is then shared by
    every trial the process flies, so it must hold no state between calls). The factory must be a user module's
    (own_factory). ConfigError naming ``policy`` otherwise."""
    args = dict(policy_args or {})
    if callable(policy):
        if args:
            raise ConfigError("policy_args", "apply only to a policy named as 'package.module:factory'", args)
        return policy
    if not isinstance(policy, str) or ":" not in policy:
        raise ConfigError("policy", "must be a callable (observation -> action) or 'package.module:factory'", policy)
    try:
        key = (policy, json.dumps(args, sort_keys=True))
    except TypeError:
        raise ConfigError("policy_args", "must be a table of JSON values (the factory's keyword arguments)",
                          args) from None
    if key not in _LOADED:
        own_factory(policy, policy.partition(":")[0])
        factory = import_object(policy, "policy")
        own_factory(policy, getattr(factory, "__module__", None))
        try:
            made = factory(**args)
        except Exception as exc:
            where = user_location(exc)
            raise ConfigError("policy", f"the factory raised {one_line(exc)}" + (f" (at {where})" if where else ""),
                              policy) from exc
        if not callable(made):
            raise ConfigError("policy", "the factory must return a callable (observation -> action)", policy)
        _LOADED[key] = made
    return _LOADED[key]


def own_factory(policy: str, module) -> None:
    """ConfigError naming ``policy`` unless ``module`` (the named module, then the module the factory was defined
    in) is a user module: not of Python's standard library (builtins, os, subprocess, ...) nor pbdyn's. The factory
    is called with parameters that a bench's --params or a scenario file supply, so a name such as "os:system" or
    "builtins:eval" must not reach a call; this is a guard against such names, not a sandbox (docs/gym.md)."""
    top = module.partition(".")[0] if isinstance(module, str) else ""
    if not top or top in sys.stdlib_module_names or top == "pbdyn":
        where = "it is defined in no module" if not top else f"{top!r} is " + \
            ("pbdyn's own package" if top == "pbdyn" else "in Python's standard library")
        raise ConfigError("policy", f"must name a factory defined in a module of your own ({where}; pbdyn calls "
                          "the factory with policy_args)", policy)


class PolicyPlanner:
    """A trajectory planner that flies a policy (module docstring).

    context: the trial's PlannerContext (pbdyn builds the planner as ``PolicyPlanner(context, **trajectory_params)``;
    None when you build it yourself: everything it needs comes from the View). policy: a callable (observation ->
    action) or "package.module:factory" (load_policy); tracks: K, the nearest tracks observed (as AvoidEnv's
    ``tracks``, default 8); patch: P, the occupancy patch observed (as AvoidEnv's ``patch``, default 0);
    policy_args: the factory's keyword arguments (e.g. a model file's path)."""

    def __init__(self, context=None, policy=None, tracks: int = 8, policy_args: Mapping | None = None,
                 patch: int = 0):
        if policy is None:
            raise ConfigError("policy", "is required: a callable (observation -> action) or 'package.module:factory' "
                              "(`params` '{\"policy\": \"package.module:factory\"}')", None,
                              show_value=False)
        self.context = context
        self.policy = load_policy(policy, policy_args)
        self.tracks, _, self.patch = check_observed(tracks, 0, patch, getattr(context, "dims", 2))
        self._view = None
        self._action: np.ndarray | None = None

    def act(self, view) -> np.ndarray:
        """The policy's action for ``view``, checked and clipped to [-1, 1] as AvoidEnv does (float64 [d + 1]); the
        policy is called once per view (the same View object reaches plan() and the gaze's yaw_rate())."""
        if view is not self._view:
            if self.patch and view.dims == 3:
                check_observed(self.tracks, 0, self.patch, 3)
            obs = observe_view(view, self.tracks, 0, self.patch)
            try:
                raw = self.policy(obs)
            except Exception as exc:
                where = user_location(exc)
                raise ConfigError("policy", f"raised {one_line(exc)} at t = {view.t:g} s"
                                  + (f" (at {where})" if where else ""), None, show_value=False) from exc
            self._action = policy_action(raw, view.dims)
            self._view = view
            _LAST.step = (view, self._action)
        return self._action

    def replan_check(self, view) -> bool:
        """Always True: the policy acts every step."""
        return True

    def plan(self, view) -> Trajectory:
        """Two samples at t0 = view.t, dt = view.dt (world frame): sample 0 the view's position, velocity and
        acceleration (m, m/s, m/s^2); sample 1 the state the action's acceleration command reaches after one step,
        pbdyn.sim.guard.integrate (|a| <= a_max, |v| <= v_max, trapezoid rule), as AvoidEnv executes it."""
        a = self.act(view)
        lim = view.limits
        nxt = integrate(command(a, lim), view.position, view.velocity, lim, view.dt)
        p = np.array([view.position, nxt.position])
        v = np.array([view.velocity, nxt.velocity])
        acc = np.array([view.acceleration, nxt.acceleration])
        return Trajectory.of_owned(view.t, view.dt, p, v, acc)

    def yaw_rate(self, view) -> float:
        """The policy's yaw rate for ``view`` (rad/s, counter-clockwise): action[d] * the yaw-rate limit."""
        return command(self.act(view), view.limits).yaw_rate


class PolicyGaze:
    """The gaze planner of a policy: the yaw rate (rad/s) of the action the PolicyPlanner took from the same view.

    Built by pbdyn with no parameters (``--gaze pbdyn.gym.policy_planner:PolicyGaze``), it reads the action of the
    PolicyPlanner of its trial, which plans just before the gaze is asked, in the same thread. ``planner``: that
    PolicyPlanner given directly (policy_pair); ``policy``, ``tracks``, ``policy_args``, ``patch``: a policy of its
    own (as PolicyPlanner's), asked when the view was not planned from by a PolicyPlanner (e.g. beside another
    trajectory planner). fov_deg is None: the scenario's sensor field of view, as in AvoidEnv."""

    fov_deg = None

    def __init__(self, context=None, policy=None, tracks: int = 8, policy_args: Mapping | None = None,
                 patch: int = 0, *, planner: PolicyPlanner | None = None):
        self.context = context
        if planner is None and policy is not None:
            planner = PolicyPlanner(context, policy, tracks, policy_args, patch)
        elif policy_args:
            raise ConfigError("policy_args", "apply only with a policy", dict(policy_args))
        self.planner = planner

    def yaw_rate(self, view, trajectory) -> float:
        """The yaw rate (rad/s, counter-clockwise) for the step from view.t: action[d] * the yaw-rate limit."""
        if self.planner is not None:
            return self.planner.yaw_rate(view)
        last = getattr(_LAST, "step", None)
        if last is None or last[0] is not view:
            raise ConfigError("gaze", "PolicyGaze without a policy flies only with PolicyPlanner as the trajectory "
                              "planner (or give it policy=...)", None, show_value=False)
        return command(last[1], view.limits).yaw_rate


def policy_action(action, dims: int) -> np.ndarray:
    """``action`` as AvoidEnv takes it: d + 1 finite numbers, clipped to [-1, 1] (float64). ConfigError naming
    ``policy`` otherwise."""
    a = np.asarray(action, dtype=float)
    if a.shape != (dims + 1,) or not np.isfinite(a).all():
        raise ConfigError("policy", f"must return {dims + 1} finite numbers (AvoidEnv's action)", action)
    return np.clip(a, -1.0, 1.0)


def policy_pair(policy, *, tracks: int = 8, policy_args: Mapping | None = None,
                patch: int = 0) -> tuple[PolicyPlanner, PolicyGaze]:
    """(trajectory planner, gaze planner) instances that fly ``policy`` (a callable or "package.module:factory")
    with one policy call per step, for ``pbdyn.run_trial(..., planner=..., gaze=...)``; ``tracks`` and ``patch`` as
    the AvoidEnv it was trained in. Each trial needs a fresh pair only if the policy keeps state between calls (the
    pair itself keeps none across trials)."""
    planner = PolicyPlanner(None, policy, tracks, policy_args, patch)
    return planner, PolicyGaze(planner=planner)


__all__ = ["Policy", "PolicyGaze", "PolicyPlanner", "load_policy", "own_factory", "policy_action", "policy_pair"]
