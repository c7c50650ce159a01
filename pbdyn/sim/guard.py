"""The guarded step (docs/architecture.md "The guarded step"): the trial core executes a next state only within the
MAV's limits, whoever proposes it -- an agent's plan, a Gymnasium policy, a test.

Under the physical profile the state at t_k+1 (p1, v1, a1) must satisfy, against the state at t_k (p0, v0), the MAV's
limits and the plan contract's step bounds (pbdyn.sim.contract; docs/design.md "The plan contract"):

    |v1| <= v_max,   |a1| <= a_max,   |v1 - v0| <= a_max dt,   |p1 - p0 - (v0 + v1) dt / 2| <= a_max dt^2 / 4,

with the contract's relative tolerance (1e-9), and the two step bounds widened by the contract's start tolerance
(1e-6 m, m/s): a plan's sample 0 may lie that far from the state it was planned from, so the first step of a new
plan is measured from the state itself. A breach ends the trial as ``invalid_plan`` with a reason naming the bound.
Under the thesis_program profile (docs/profiles.md) the core executes as the thesis' program did -- positions on its
0.1 m pixels, its braking, its plans' accelerations -- which breaks these bounds by design; there the guard checks
the form only (finite float vectors of the world's dimension, a finite yaw rate).

``Accel`` is the lower-level action for callers without a planner: an acceleration command and a yaw rate, which
the core clips to the limits and integrates exactly (``integrate``), so it always passes the guard.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pbdyn.planning.view import MAVLimits
from pbdyn.sim.contract import EXPLAIN, REL_TOL, START_TOL

GUARD_CHECKS = ("form", "speed", "acceleration", "velocity_step", "position_step")
"""The guard's checks, in the order they are applied."""

_EXPLAIN = {**EXPLAIN, "form": "p, v, a must be finite float vectors [d] of the world's dimension d and the yaw "
            "rate a finite number"}


@dataclass(frozen=True)
class Action:
    """What the MAV does from t_k to t_k+1: its state at t_k+1 (p m, v m/s, a m/s^2, world frame [d]), its yaw
    rate (rad/s; clipped to the limit by the core) and its consecutive planning failures (for the deadlock rule; 0
    for callers without a planner). The core executes it only within the MAV's limits (pbdyn.sim.guard); callers
    without a planner may give an acceleration command instead (pbdyn.sim.guard.Accel)."""

    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    yaw_rate: float
    consecutive_failures: int = 0


@dataclass(frozen=True)
class Accel:
    """An acceleration command for one step: ``acceleration`` [d] (m/s^2, world frame; clipped to a_max by its
    norm) and ``yaw_rate`` (rad/s; clipped to the yaw-rate limit). See integrate()."""

    acceleration: np.ndarray
    yaw_rate: float = 0.0


def integrate(accel: Accel, position: np.ndarray, velocity: np.ndarray, limits: MAVLimits, dt: float) -> Action:
    """The Action that executes ``accel`` from (position m, velocity m/s) over one step of ``dt`` s within
    ``limits``: a = the command clipped to norm a_max; v1 = v0 + a dt, scaled back onto the ball |v| <= v_max when it
    leaves it (and a = (v1 - v0) / dt then); p1 = p0 + (v0 + v1) dt / 2 (exact for a constant acceleration).
    ValueError for a command that is not a finite vector of the world's dimension."""
    d = position.shape[0]
    a = np.asarray(accel.acceleration, dtype=float)
    rate = float(accel.yaw_rate)
    if a.shape != (d,) or not np.isfinite(a).all() or not math.isfinite(rate):
        raise ValueError(f"acceleration command must be a finite vector of {d} numbers and a finite yaw rate "
                         f"(got {np.asarray(accel.acceleration).tolist()!r}, yaw rate {accel.yaw_rate!r})")
    norm = math.sqrt(float(a @ a))
    if norm > limits.a_max:
        a = a * (limits.a_max / norm)
    v1 = velocity + a * dt
    speed = math.sqrt(float(v1 @ v1))
    if speed > limits.v_max:
        v1 = v1 * (limits.v_max / speed)
        a = (v1 - velocity) / dt
    p1 = position + 0.5 * (velocity + v1) * dt
    return Action(p1, v1, a, rate, 0)


def breach(action: Action, position: np.ndarray, velocity: np.ndarray, limits: MAVLimits, dt: float,
           physical: bool) -> str | None:
    """Why the core refuses to execute ``action`` from (position m, velocity m/s) over ``dt`` s: one line naming the
    broken check, its value and bound; None when the action may be executed. See the module docstring."""
    d = position.shape[0]
    p1, v1, a1 = action.position, action.velocity, action.acceleration
    if not (type(p1) is np.ndarray and type(v1) is np.ndarray and type(a1) is np.ndarray
            and p1.shape == v1.shape == a1.shape == (d,) and p1.dtype.kind == v1.dtype.kind == a1.dtype.kind == "f"):
        return _reason("form", math.nan, math.nan, "")
    # on d = 2 or 3 values, Python floats cost less than numpy's per-call dispatch (this runs every step)
    pl, vl, al, p0, v0 = p1.tolist(), v1.tolist(), a1.tolist(), position.tolist(), velocity.tolist()
    speed2 = acc2 = dv2 = gap2 = 0.0
    half = 0.5 * dt
    for j in range(d):
        dv = vl[j] - v0[j]
        gap = pl[j] - p0[j] - (v0[j] + vl[j]) * half
        speed2 += vl[j] * vl[j]
        acc2 += al[j] * al[j]
        dv2 += dv * dv
        gap2 += gap * gap
    try:
        rate = float(action.yaw_rate)
    except (TypeError, ValueError):
        rate = math.nan
    if not math.isfinite(speed2 + acc2 + dv2 + gap2 + rate):     # a NaN or an infinity anywhere
        return _reason("form", math.nan, math.nan, "")
    if not physical:
        return None
    grow = 1.0 + REL_TOL
    if speed2 > (limits.v_max * grow) ** 2:
        return _reason("speed", math.sqrt(speed2), limits.v_max, "m/s")
    if acc2 > (limits.a_max * grow) ** 2:
        return _reason("acceleration", math.sqrt(acc2), limits.a_max, "m/s^2")
    step_v = limits.a_max * dt * grow + START_TOL
    if dv2 > step_v * step_v:
        return _reason("velocity_step", math.sqrt(dv2), step_v, "m/s")
    step_p = limits.a_max * dt * dt / 4.0 * grow + START_TOL * (1.0 + half)
    if gap2 > step_p * step_p:
        return _reason("position_step", math.sqrt(gap2), step_p, "m")
    return None


def _reason(check: str, value: float, limit: float, unit: str) -> str:
    if math.isnan(value):
        return f"next state broke {check} ({_EXPLAIN[check]})"
    return f"next state broke {check}: {value:.9g} {unit} > {limit:.9g} {unit} ({_EXPLAIN[check]})"
