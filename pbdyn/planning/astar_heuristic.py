"""Admissible A* heuristic of the global motion primitives planner (thesis A-1 eq. A-1; Liu et al. 2017, LQMT).

The edge cost of a constant-acceleration primitive of duration T is |a|^2 T + rho T, so the cost of any trajectory
of duration tau is J = int |a|^2 dt + rho tau. The bound used here is the linear-quadratic minimum-time (LQMT) value
with **free final time and free final velocity**, measured to the **edge of the goal ball**:

    h(p, v) = min over tau >= tau_lb of  3 g(tau)^2 / tau^3 + rho tau,
    g(tau)  = max(0, |p_goal - p - v tau| - r_goal).

3 |e|^2 / tau^3 is the least control energy that moves a double integrator by e = p(tau) - p - v tau in time tau
when the final velocity is free (a(t) = 3 e (tau - t) / tau^3); the closest point of the goal ball is at
g(tau) from p + v tau. tau_lb is a lower bound on the time any trajectory that respects |v| <= v_max and
|a| <= a_max needs to reach the ball (its speed can grow from min(|v|, v_max) at most at a_max and never exceeds
v_max). Every feasible trajectory therefore costs at least h, so h never overestimates.

Eq. A-1 of the thesis is the LQMT cost with T fixed and the final state fixed at the goal with zero velocity; both
restrictions can overestimate the cost-to-go (a trajectory that arrives at speed, earlier or later than T, can be
cheaper), so it is not used.

The minimum over tau has no closed form with the ball; it is bounded from below, never approximated from above:
[tau_lb, tau_hi] is split into ``n_intervals`` geometric intervals [ta, tb]; on each, 3 g_min^2 / tb^3 + rho ta
bounds f from below, where g_min uses the distance from p_goal - p to the segment {v tau, tau in [ta, tb]};
beyond tau_hi = f_probe / rho, f(tau) >= rho tau >= f_probe (a value of f at a feasible tau).
"""

from __future__ import annotations

import numpy as np

_PROBES = np.array([1.0, 1.25, 1.5, 2.0, 3.0, 5.0, 8.0])


def min_time_bound(dist: np.ndarray, speed: np.ndarray, v_max: float, a_max: float) -> np.ndarray:
    """Lower bound (s) on the time to travel ``dist`` (m, [N]) starting at ``speed`` (m/s, [N], clipped to v_max)
    when speed grows at most at a_max (m/s^2) up to v_max (m/s): the 1D accelerate-then-cruise time."""
    dist = np.maximum(np.asarray(dist, dtype=float), 0.0)
    s0 = np.minimum(np.asarray(speed, dtype=float), v_max)
    t1 = (v_max - s0) / a_max
    d1 = s0 * t1 + 0.5 * a_max * t1 * t1
    t_acc = (np.sqrt(s0 * s0 + 2.0 * a_max * dist) - s0) / a_max
    return np.where(dist <= d1, t_acc, t1 + (dist - d1) / v_max)


def lqmt_lower_bound(delta: np.ndarray, vel: np.ndarray, goal_radius: float, rho: float, v_max: float,
                     a_max: float, velocity_set: np.ndarray | None = None, n_intervals: int = 24) -> np.ndarray:
    """The heuristic h [N] (cost units (m/s^2)^2 s) for offsets delta = p_goal - p [N, d] (m) and velocities
    vel [N, d] (m/s); see the module docstring. 0 for states inside the goal ball.

    velocity_set [V, d] (m/s), optional: velocities whose convex hull (with the state's own velocity) contains
    every velocity the trajectory can take (a lattice's velocities); tau_lb is then also at least
    (|delta| - r_goal) / max over the hull of v . delta / |delta| (the progress toward the ball per second)."""
    delta = np.atleast_2d(np.asarray(delta, dtype=float))
    vel = np.atleast_2d(np.asarray(vel, dtype=float))
    n = delta.shape[0]
    out = np.zeros(n)
    dist = np.sqrt(np.einsum("nd,nd->n", delta, delta))
    outside = dist > goal_radius
    if not outside.any():
        return out
    delta, vel = delta[outside], vel[outside]
    vv = np.einsum("nd,nd->n", vel, vel)
    t_lb = min_time_bound(dist[outside] - goal_radius, np.sqrt(vv), v_max, a_max)
    if velocity_set is not None and len(velocity_set):
        u = delta / dist[outside][:, None]
        support = np.maximum((u @ np.asarray(velocity_set, dtype=float).T).max(axis=1),
                             np.einsum("nd,nd->n", u, vel))
        t_lb = np.maximum(t_lb, (dist[outside] - goal_radius) / np.maximum(support, 1e-9))
    t_lb = np.maximum(t_lb, 1e-9)

    def f(tau: np.ndarray) -> np.ndarray:  # tau [m, k] -> f [m, k]
        e = delta[:, None, :] - vel[:, None, :] * tau[..., None]
        g = np.maximum(np.sqrt(np.einsum("mkd,mkd->mk", e, e)) - goal_radius, 0.0)
        return 3.0 * g * g / tau ** 3 + rho * tau

    upper = f(t_lb[:, None] * _PROBES[None, :]).min(axis=1)  # a value of f at a feasible time
    t_hi = np.maximum(upper / rho, t_lb)
    frac = np.arange(n_intervals + 1) / n_intervals
    edges = t_lb[:, None] * (t_hi / t_lb)[:, None] ** frac[None, :]
    ta, tb = edges[:, :-1], edges[:, 1:]
    dv = np.einsum("nd,nd->n", delta, vel)
    tau_star = np.where(vv > 0, dv / np.where(vv > 0, vv, 1.0), 0.0)
    tau = np.clip(tau_star[:, None], ta, tb)
    e = delta[:, None, :] - vel[:, None, :] * tau[..., None]
    g = np.maximum(np.sqrt(np.einsum("mkd,mkd->mk", e, e)) - goal_radius, 0.0)
    lower = (3.0 * g * g / tb ** 3 + rho * ta).min(axis=1)
    out[outside] = np.minimum(lower, upper)
    return out
