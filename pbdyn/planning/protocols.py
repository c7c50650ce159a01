"""Extension points: trajectory and gaze planners (docs/design.md "Planner protocols", thesis 2-4-3).

User planners only need these methods (duck typing); built-ins are listed in pbdyn.planning.registry.
A planner class is constructed as ``Class(context, **params)`` where params is the scenario's params table.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from pbdyn.planning.trajectory import Trajectory
from pbdyn.planning.view import MAVLimits, View


@dataclass(frozen=True)
class PlannerContext:
    """Fixed facts of a trial, given to planner constructors.

    Attributes:
        dims: spatial dimension d (2 or 3).
        dt: world step (s).
        limits: MAV radius (m), v_max (m/s), a_max (m/s^2), yaw-rate limit (rad/s).
        bounds_lo, bounds_hi: arena box [d] (m).
        seed: a per-trial integer seed; a planner that needs randomness makes np.random.default_rng(seed).
        physical: True under the "physical" profile (every plan must keep |v| <= v_max and |a| <= a_max, see
            pbdyn.sim.contract); False under "thesis_program", whose plans are checked for continuity only.
    """

    dims: int
    dt: float
    limits: MAVLimits
    bounds_lo: np.ndarray
    bounds_hi: np.ndarray
    seed: int = 0
    physical: bool = True


@runtime_checkable
class TrajectoryPlanner(Protocol):
    """Plans the MAV's trajectory (thesis Algorithm 1).

    replan_check(view) -> bool: True if a new plan is needed at view.t (view.trajectory is the plan in execution,
        None before the first plan or after a failure).
    plan(view) -> Trajectory | None: a trajectory whose sample 0 is the MAV state at view.t (t0 = view.t,
        dt = view.dt, p/v/a [K, d] in m, m/s, m/s^2, world frame, K >= 2), respecting |v| <= v_max and
        |a| <= a_max at every sample; None on failure (the MAV then brakes and the failure is counted).
    """

    def replan_check(self, view: View) -> bool: ...

    def plan(self, view: View) -> Trajectory | None: ...


@runtime_checkable
class GazePlanner(Protocol):
    """Chooses the MAV's yaw rate (thesis 4-1-2).

    yaw_rate(view, trajectory) -> float: yaw rate (rad/s, counter-clockwise positive) for the step from view.t to
        view.t + dt; trajectory is the plan in execution (or None while braking). The trial clips it to
        +-limits.yaw_rate.
    Optional attribute fov_deg: float — a sensor FOV (deg) this gaze planner imposes (FullRange: 360).
    """

    def yaw_rate(self, view: View, trajectory: Trajectory | None) -> float: ...
