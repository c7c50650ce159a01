"""The plan contract (docs/design.md "The plan contract"): what every returned trajectory must satisfy.

A plan made at time t (s) with the MAV at (p, v) must have t0 = t, dt = the world step, sample 0 = (p, v) within
1e-6, |v_k| <= v_max and |a_k| <= a_max at every sample, and consecutive samples reachable with an acceleration of
norm <= a_max whatever the curve between them:

    |v_k+1 - v_k| <= a_max dt    and    |p_k+1 - p_k - (v_k + v_k+1) dt / 2| <= a_max dt^2 / 4.

The second bound is exact: over one step, any acceleration profile of norm <= a_max moves the position at most
a_max dt^2 / 4 away from the trapezoid rule's estimate (the extreme is +a_max for half the step, -a_max for the
other half). Limits and bounds carry a relative tolerance of 1e-9.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pbdyn.jit import njit
from pbdyn.planning.trajectory import Trajectory

START_TOL = 1e-6   # m and m/s: sample 0 against the MAV's current state
REL_TOL = 1e-9     # relative tolerance on every limit and bound
TIME_TOL = 1e-9    # s: t0 against now, dt against the world step (relative to max(1, |value|))

CHECKS = ("type", "shape", "finite", "t0", "dt", "start_position", "start_velocity", "speed", "acceleration",
          "velocity_step", "position_step")
"""Every check's name, in the order they are applied."""


@dataclass(frozen=True)
class PlanViolation:
    """One broken rule of the plan contract: the check's name, the sample index (-1: the whole plan), the value
    found and the bound it exceeded (SI units of the check)."""

    check: str
    sample: int
    value: float
    limit: float
    unit: str = ""

    @property
    def reason(self) -> str:
        """One readable line, e.g. "plan broke speed at sample 3: 8.000000 m/s > 4.000000 m/s"."""
        where = "" if self.sample < 0 else f" at sample {self.sample}"
        if math.isnan(self.value):
            return f"plan broke {self.check}{where} ({EXPLAIN[self.check]})"
        unit = f" {self.unit}" if self.unit else ""
        return (f"plan broke {self.check}{where}: {self.value:.9g}{unit} > {self.limit:.9g}{unit} "
                f"({EXPLAIN[self.check]})")


EXPLAIN = {
    "type": "plan() must return a pbdyn Trajectory or None",
    "shape": "p, v, a must be [K, d] arrays with K >= 2 and d the world's dimension",
    "finite": "every sample must be finite",
    "t0": "t0 must be the time of the view",
    "dt": "samples must be spaced by the world step",
    "start_position": "sample 0 must be the MAV's current position",
    "start_velocity": "sample 0 must be the MAV's current velocity",
    "speed": "|v| <= v_max",
    "acceleration": "|a| <= a_max",
    "velocity_step": "|v_k+1 - v_k| <= a_max dt",
    "position_step": "|p_k+1 - p_k - (v_k + v_k+1) dt/2| <= a_max dt^2/4",
}
"""Each check's rule, as its message states it (the guard's step bounds, pbdyn.sim.guard, are the same)."""


def _first_over(values: np.ndarray, limit: float, check: str, unit: str, offset: int = 0) -> PlanViolation | None:
    over = np.flatnonzero(values > limit * (1.0 + REL_TOL))
    if over.size == 0:
        return None
    i = int(over[0])
    return PlanViolation(check, i + offset, float(values[i]), float(limit), unit)


def plan_violations(traj, *, t: float, dt: float, position: np.ndarray, velocity: np.ndarray, v_max: float,
                    a_max: float, physical: bool = True, first_only: bool = False) -> list[PlanViolation]:
    """Every broken check of the plan contract for ``traj`` returned at time ``t`` (s) with the MAV at
    ``position`` (m) / ``velocity`` (m/s), world step ``dt`` (s) and limits ``v_max`` (m/s), ``a_max`` (m/s^2);
    per check, the first offending sample. ``physical=False`` checks only the form and continuity (type, shape,
    finite, t0, dt, sample 0). ``first_only`` stops at the first violation. An empty list: the plan is valid."""
    found: list[PlanViolation] = []

    def add(v: PlanViolation | None) -> bool:
        if v is not None:
            found.append(v)
        return bool(found) and first_only

    if not isinstance(traj, Trajectory):
        return [PlanViolation("type", -1, math.nan, math.nan)]
    position = np.asarray(position, dtype=float)
    d = position.shape[0]
    p, v, a = traj.p, traj.v, traj.a
    if p.shape[1] != d or p.shape[0] < 2:
        return [PlanViolation("shape", -1, float(p.shape[0] if p.shape[1] == d else p.shape[1]),
                              float(2 if p.shape[1] == d else d))]
    bad = ~(np.isfinite(p).all(axis=1) & np.isfinite(v).all(axis=1) & np.isfinite(a).all(axis=1))
    if bad.any() or not (math.isfinite(traj.t0) and math.isfinite(traj.dt)):
        return [PlanViolation("finite", int(np.argmax(bad)) if bad.any() else -1, math.nan, math.nan)]
    if add(_first_over(np.array([abs(traj.t0 - t)]), TIME_TOL * max(1.0, abs(t)), "t0", "s", -1)):
        return found
    if add(_first_over(np.array([abs(traj.dt - dt)]), TIME_TOL * max(1.0, dt), "dt", "s", -1)):
        return found
    if add(_first_over(np.array([float(np.linalg.norm(p[0] - position))]), START_TOL, "start_position", "m")):
        return found
    if add(_first_over(np.array([float(np.linalg.norm(v[0] - np.asarray(velocity, dtype=float)))]), START_TOL,
                       "start_velocity", "m/s")):
        return found
    if not physical:
        return found
    if add(_first_over(np.linalg.norm(v, axis=1), v_max, "speed", "m/s")):
        return found
    if add(_first_over(np.linalg.norm(a, axis=1), a_max, "acceleration", "m/s^2")):
        return found
    step = traj.dt
    if add(_first_over(np.linalg.norm(v[1:] - v[:-1], axis=1), a_max * step, "velocity_step", "m/s", 1)):
        return found
    gap = p[1:] - p[:-1] - 0.5 * (v[:-1] + v[1:]) * step
    add(_first_over(np.linalg.norm(gap, axis=1), a_max * step * step / 4.0, "position_step", "m", 1))
    return found


def _clearly_valid(traj, t, dt, position, velocity, v_max, a_max, physical) -> bool:
    """A fast screen of the common case: True only if every check passes with a margin (squared norms against
    slightly shrunk bounds, so rounding can never pass what plan_violations would refuse); False sends the plan
    to plan_violations, which decides."""
    if type(traj) is not Trajectory:
        return False
    p, v, a = traj.p, traj.v, traj.a
    if p.shape[1] != position.shape[0] or p.shape[0] < 2 or velocity.shape != position.shape:
        return False
    if not (abs(traj.t0 - t) <= TIME_TOL * max(1.0, abs(t)) and abs(traj.dt - dt) <= TIME_TOL * max(1.0, dt)):
        return False
    shrink = 1.0 - 1e-12
    start2 = START_TOL * START_TOL * shrink
    if not physical:
        return _within(p, v, a, position, velocity, start2, False, 0.0, 0.0, 0.0, 0.0, 0.0)
    step = traj.dt
    vmax2 = (v_max * (1.0 + REL_TOL)) ** 2 * shrink
    amax2 = (a_max * (1.0 + REL_TOL)) ** 2 * shrink
    dvmax2 = (a_max * step * (1.0 + REL_TOL)) ** 2 * shrink
    gapmax2 = (a_max * step * step / 4.0 * (1.0 + REL_TOL)) ** 2 * shrink
    return _within(p, v, a, position, velocity, start2, True, step, vmax2, amax2, dvmax2, gapmax2)


@njit(cache=True, nogil=True)
def _within(p, v, a, position, velocity, start2, physical, step, vmax2, amax2, dvmax2, gapmax2) -> bool:
    """_clearly_valid's bounds on samples p, v, a [K, d]: squared distances of sample 0 from ``position`` and
    ``velocity`` <= start2, and, when ``physical``, every sample's squared speed and acceleration and every step's
    (``step`` s) squared velocity change and position gap (pbdyn.sim.contract) within vmax2, amax2, dvmax2,
    gapmax2; otherwise only that every value is finite. NaN passes no bound."""
    n, d = p.shape
    dp2 = 0.0
    dv2 = 0.0
    for j in range(d):
        e = p[0, j] - position[j]
        f = v[0, j] - velocity[j]
        dp2 += e * e
        dv2 += f * f
    if not (dp2 <= start2 and dv2 <= start2):
        return False
    if not physical:
        for k in range(n):
            for j in range(d):
                if not (np.isfinite(p[k, j]) and np.isfinite(v[k, j]) and np.isfinite(a[k, j])):
                    return False
        return True
    for k in range(n):
        sv = 0.0
        sa = 0.0
        for j in range(d):
            sv += v[k, j] * v[k, j]
            sa += a[k, j] * a[k, j]
        if not (sv <= vmax2 and sa <= amax2):
            return False
    for k in range(n - 1):
        sdv = 0.0
        sgap = 0.0
        for j in range(d):
            dv = v[k + 1, j] - v[k, j]
            gap = p[k + 1, j] - p[k, j] - 0.5 * (v[k, j] + v[k + 1, j]) * step
            sdv += dv * dv
            sgap += gap * gap
        if not (sdv <= dvmax2 and sgap <= gapmax2):
            return False
    return True


def check_plan(traj, *, t: float, dt: float, position: np.ndarray, velocity: np.ndarray, v_max: float,
               a_max: float, physical: bool = True) -> PlanViolation | None:
    """The first violation of the plan contract (arguments as plan_violations), or None."""
    position = np.asarray(position, dtype=float)
    velocity = np.asarray(velocity, dtype=float)
    if _clearly_valid(traj, t, dt, position, velocity, v_max, a_max, physical):
        return None
    found = plan_violations(traj, t=t, dt=dt, position=position, velocity=velocity, v_max=v_max, a_max=a_max,
                            physical=physical, first_only=True)
    return found[0] if found else None
