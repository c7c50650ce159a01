"""Admissible A* heuristic of the global motion primitives planner (thesis A-1 eq. A-1; Liu et al. 2017, LQMT).

The edge cost of a constant-acceleration primitive of duration T is |a|^2 T + rho T, so a trajectory of duration
tau costs J = int |a|^2 dt + rho tau. The bound is the linear-quadratic minimum-time (LQMT) value with **free final
time and free final velocity**, measured to the **edge of the goal ball** (radius r):

    h(p, v) = min over tau >= tau_lb of  f(tau) = 3 g(tau)^2 / tau^3 + rho tau,
    g(tau)  = max(0, |p_goal - p - v tau| - r).

3 |e|^2 / tau^3 is the least control energy that moves a double integrator by e = p(tau) - p - v tau in time tau
when the final velocity is free (a(t) = 3 e (tau - t) / tau^3), and the goal ball's closest point is g(tau) away
from p + v tau. tau_lb is a lower bound on the time to reach the ball:
  * speed grows from min(|v|, v_max) at most at a_max and never exceeds v_max (min_time_bound), and
  * optionally, with a velocity set V (the planner's lattice velocities): velocities stay in the convex hull of
    V and v, so progress toward the goal is at most max over it of v . u per second (u: unit goal direction).
Every trajectory the planner can return (|v| <= v_max, |a| <= a_max, velocities in that hull) therefore costs at
least h: h never overestimates. Without V it bounds every feasible trajectory; with V, every lattice path.

Eq. A-1 of the thesis is the LQMT cost with T fixed and the final state fixed at the goal with zero velocity; both
restrictions can overestimate the cost-to-go (arriving at speed, or at another time, can be cheaper), so it is not
used.

The minimum over tau has no closed form with the ball; it is bounded from below, never approximated from above:
[tau_lb, RATIO_MAX tau_lb] is split into geometric intervals [ta, tb]; on each, 3 g_min^2 / tb^3 + rho ta <= f,
with g_min from the distance of p_goal - p to the segment {v tau : tau in [ta, tb]}; beyond, f >= rho tau.
"""

from __future__ import annotations

import numpy as np

RATIO_MAX = 4.0
N_INTERVALS = 16
_RATIOS = RATIO_MAX ** (np.arange(N_INTERVALS + 1) / N_INTERVALS)


def min_time_bound(dist: np.ndarray, speed: np.ndarray, v_max: float, a_max: float) -> np.ndarray:
    """Lower bound (s) on the time to travel ``dist`` (m, [N]) starting at ``speed`` (m/s, [N], clipped to v_max)
    when speed grows at most at a_max (m/s^2) up to v_max (m/s): the 1D accelerate-then-cruise time."""
    dist = np.maximum(np.asarray(dist, dtype=float), 0.0)
    s0 = np.minimum(np.asarray(speed, dtype=float), v_max)
    t1 = (v_max - s0) / a_max
    d1 = (s0 + 0.5 * a_max * t1) * t1
    t_acc = (np.sqrt(s0 * s0 + 2.0 * a_max * dist) - s0) / a_max
    return np.where(dist <= d1, t_acc, t1 + (dist - d1) / v_max)


def lqmt_lower_bound(delta: np.ndarray, vel: np.ndarray, goal_radius: float, rho: float, v_max: float,
                     a_max: float, velocity_set: np.ndarray | None = None) -> np.ndarray:
    """The heuristic h [N] (cost units (m/s^2)^2 s) for offsets delta = p_goal - p [N, d] (m) and velocities
    vel [N, d] (m/s); 0 inside the goal ball. velocity_set [V, d] (m/s), optional: see the module docstring."""
    delta = np.atleast_2d(np.asarray(delta, dtype=float))
    vel = np.atleast_2d(np.asarray(vel, dtype=float))
    dist = np.sqrt(np.einsum("nd,nd->n", delta, delta))
    gap = dist - goal_radius
    vv = np.einsum("nd,nd->n", vel, vel)
    dv = np.einsum("nd,nd->n", delta, vel)
    t_lb = min_time_bound(gap, np.sqrt(vv), v_max, a_max)
    if velocity_set is not None and len(velocity_set):
        safe = np.maximum(dist, 1e-300)
        support = np.maximum((delta @ np.asarray(velocity_set, dtype=float).T).max(axis=1), dv) / safe
        t_lb = np.maximum(t_lb, gap / np.maximum(support, 1e-12))
    t_lb = np.maximum(t_lb, 1e-9)
    edges = t_lb[:, None] * _RATIOS[None, :]
    ta, tb = edges[:, :-1], edges[:, 1:]
    tau = np.clip((dv / np.maximum(vv, 1e-300))[:, None], ta, tb)
    e = delta[:, None, :] - vel[:, None, :] * tau[:, :, None]
    g = np.maximum(np.sqrt(np.einsum("nkd,nkd->nk", e, e)) - goal_radius, 0.0)
    h = np.minimum((3.0 * g * g / (tb * tb * tb) + rho * ta).min(axis=1), rho * edges[:, -1])
    return np.where(gap > 0, h, 0.0)
