"""Owl gaze planner (Chen et al. 2021, thesis ref. [17]; thesis 4-1-2, eq. 4-8, 4-9; docs/thesis-program.md).

Every ``period_s`` (0.8 s) Owl picks, among ``n_rates`` (20) evenly spaced yaw rates in [-limit, +limit], the one
minimising sum_i lambda_i f_i (eq. 4-8) and holds it until the next decision. A candidate rate w is judged by the
yaw it reaches when held for the period, psi_w = yaw + w * period_s (azimuths only, also in 3D):
- f1 goal: angle (rad) between psi_w and the MAV-to-goal direction; lambda_1 = w_goal (0.2).
- f2 velocity: angle between psi_w and the horizontal velocity; lambda_2 = w_velocity * (|v_xy| / 1 m/s)^2 (0.9).
- f3 obstacles: sum over the active tracks (each track's own mean position and velocity) of threat_j times the
  angle between psi_w and track j's bearing; the term is zero once the track is inside psi_w's FOV (the shared
  in_fov predicate, range unlimited), so bringing a threatening track into view pays off at once.
  threat_j = max(closing speed, 0) / distance (1/s), the closing speed being -d|p_j - p|/dt from the relative
  velocity; lambda_3 = w_obstacle (1.0).
- f4 unseen directions: 10-degree azimuth bins remember when their centre direction was last inside the FOV
  (in_fov at each call's yaw; initially stale); f4 = -(sum over the bins psi_w's FOV covers of
  min(age / stale_s, 1)) / (bins per FOV), in [-1, 0]; lambda_4 = w_unseen (0.1).
- f5 yaw rate: (w / limit)^2; lambda_5 = w_rate (0.05: a regulariser, half the smallest program weight).
Weights 0.2 / 0.9 (|v|/1 m/s)^2 / 1.0 / 0.1 are the thesis program's; w_rate, stale_s and the cost shapes are
pbdyn's (the thesis gives none). The program paired obstacle directions with the wrong trackers (a defect); here the
rows of view.tracks are used together. With an even n_rates (the program's 20), 0 is not a candidate.
Exact ties go to the smallest |rate|, then the counter-clockwise one.

``costs = "program"`` (the thesis_program profile, PROGRAM_PARAMS) is the thesis program's Owl as its code ran
(world frame = the program's pixel frame / 10, whose yaw is minus pbdyn's; see program_costs):
- candidates: the program's 20 rates limit * (1 - k/10), k = 0..19 (+limit first, -limit absent), judged at
  psi_w = yaw + w * period_s (0.8 s) and held for floor(period_s / dt) steps (8), re-decided after them;
- angle cost G(theta) = 0 inside the FOV half-angle, else the product of the angles (rad) from theta to the two
  FOV edges; f1 = G(psi_w - goal bearing) (1 - U(goal bearing)), f2 = (|v| / 1 m/s)^2 G(psi_w - velocity
  heading) (1 - U(velocity heading)), f3 = sum_k w_k G(psi_w - bearing of the k-th active track), f4 = U(psi_w),
  f5 weight 0;
- U: 36 bins at 0, 10, ..., 350 deg, updated at each decision by -(v period_s) . d_i / range plus 0.4 if the bin
  is inside the current FOV (strictly) else -0.05, clipped to [0, 1]; U(theta) = the nearest bin (first on ties);
- w_k = |v_j| / |p_j - p| of the track of obstacle j = k (the k-th by index, 0 if it has no active track): the
  program's pairing of the k-th active direction with the k-th tracker (docs/thesis-program.md, a defect kept
  here because this mode reproduces the program);
- a MAV at rest makes every program cost NaN, and its argmin took the first candidate: +limit.
"""

from __future__ import annotations

import math

import numpy as np

from pbdyn.perception.sensor import in_fov
from pbdyn.planning.gaze.yaw import heading, rate_candidates, tie_break_order
from pbdyn.planning.protocols import PlannerContext
from pbdyn.planning.trajectory import Trajectory
from pbdyn.planning.view import View
from pbdyn.world.geometry import wrap_angle


def _angle_between(yaws: np.ndarray, heading: np.ndarray | float) -> np.ndarray:
    """|wrap(heading - yaws)| (rad, in [0, pi]), broadcast."""
    return np.abs(wrap_angle(np.asarray(heading) - yaws))


def _check(name: str, value, *, positive: bool) -> float:
    ok = isinstance(value, (int, float)) and math.isfinite(float(value))
    ok = ok and (float(value) > 0 if positive else float(value) >= 0)
    if not ok:
        raise ValueError(f"{name} must be a finite number {'> 0' if positive else '>= 0'}, got {value!r}")
    return float(value)


class Owl:
    """Multi-objective gaze planner re-deciding every period_s (registry name "owl"; see the module docstring).

    Args: period_s (0.8 s), n_rates (20), w_goal (0.2), w_velocity (0.9, times (|v|/1 m/s)^2), w_obstacle (1.0),
    w_unseen (0.1), w_rate (0.05), bin_deg (10 deg; must divide 360), stale_s (2 s: the age at which a direction
    bin counts as fully stale). One instance per trial (it keeps the held rate and the bins' last-seen times).
    """

    PROGRAM_PARAMS: dict = {"costs": "program", "w_rate": 0.0}
    """The thesis_program profile's parameters: the program's cost shapes, rates and hold (module docstring)."""

    def __init__(self, context: PlannerContext, *, period_s: float = 0.8, n_rates: int = 20, w_goal: float = 0.2,
                 w_velocity: float = 0.9, w_obstacle: float = 1.0, w_unseen: float = 0.1, w_rate: float = 0.05,
                 bin_deg: float = 10.0, stale_s: float = 2.0, costs: str = "pbdyn"):
        if costs not in ("pbdyn", "program"):
            raise ValueError(f"costs must be 'pbdyn' or 'program', got {costs!r}")
        self.costs_rule = costs
        self.period_s = _check("period_s", period_s, positive=True)
        self.w_goal = _check("w_goal", w_goal, positive=False)
        self.w_velocity = _check("w_velocity", w_velocity, positive=False)
        self.w_obstacle = _check("w_obstacle", w_obstacle, positive=False)
        self.w_unseen = _check("w_unseen", w_unseen, positive=False)
        self.w_rate = _check("w_rate", w_rate, positive=False)
        self.stale_s = _check("stale_s", stale_s, positive=True)
        bin_deg = _check("bin_deg", bin_deg, positive=True)
        n_bins = int(round(360.0 / bin_deg))
        if n_bins < 1 or abs(n_bins * bin_deg - 360.0) > 1e-9:
            raise ValueError(f"bin_deg must divide 360, got {bin_deg!r}")
        self.limit = float(context.limits.yaw_rate)
        if costs == "program":
            if not isinstance(n_rates, int) or isinstance(n_rates, bool) or n_rates < 2 or n_rates % 2:
                raise ValueError(f"n_rates must be an even integer >= 2 with costs 'program', got {n_rates!r}")
            half = n_rates // 2
            self.rates = self.limit * (1.0 - np.arange(n_rates) / half)
            self._order = np.arange(n_rates)
            self.hold_steps = max(1, int(self.period_s // float(context.dt)))
            self.belief = np.zeros(int(round(360.0 / bin_deg)))
            self._steps_left = 0
        else:
            self.rates = rate_candidates(self.limit, n_rates, include_zero=False)
            self._order = tie_break_order(self.rates)
        self.dims = int(context.dims)
        az = -math.pi + (np.arange(n_bins) + 0.5) * (2.0 * math.pi / n_bins)
        dirs = np.zeros((n_bins, self.dims))
        dirs[:, 0], dirs[:, 1] = np.cos(az), np.sin(az)
        self.bin_azimuths = az
        self._bin_dirs = dirs                                       # horizontal unit vectors of the bin centres
        self.bin_last_seen: np.ndarray | None = None                # s, per bin
        self.held_rate = 0.0
        self._next_decision = -math.inf
        self.last_costs: np.ndarray | None = None                   # total cost per candidate at the last decision

    def _observe(self, view: View) -> None:
        t = float(view.t)
        if self.bin_last_seen is None:
            self.bin_last_seen = np.full(self.bin_azimuths.shape[0], t - self.stale_s)
        pts = self._bin_dirs * (0.5 * float(view.range_m))
        self.bin_last_seen[in_fov(view.yaw, pts, view.fov_deg, view.range_m, view.vfov_deg)] = t

    def costs(self, view: View) -> np.ndarray:
        """Total cost (eq. 4-8) of each candidate rate in ``self.rates`` for the view (needs one prior observe)."""
        t = float(view.t)
        c = self.rates.shape[0]
        yaws = view.yaw + self.rates * self.period_s
        fov = float(view.fov_deg)
        cost = self.w_rate * (self.rates / self.limit) ** 2
        h = heading(view.goal - view.position)
        if h is not None and self.w_goal > 0:
            cost = cost + self.w_goal * _angle_between(yaws, h)
        h = heading(view.velocity)
        if h is not None and self.w_velocity > 0:
            speed = math.hypot(float(view.velocity[0]), float(view.velocity[1]))
            cost = cost + self.w_velocity * speed * speed * _angle_between(yaws, h)
        tracks = view.tracks
        if len(tracks) and self.w_obstacle > 0 and fov < 360.0:
            rel = tracks.position - view.position                                # [M, d], row j = track j
            rel_v = tracks.velocity - view.velocity
            dist = np.sqrt(np.sum(rel * rel, axis=1))
            closing = -np.sum(rel * rel_v, axis=1) / np.maximum(dist, 1e-9)
            threat = np.maximum(closing, 0.0) / np.maximum(dist, 1e-9)          # 1/s
            bearing = np.arctan2(rel[:, 1], rel[:, 0])
            inside = in_fov(yaws[:, None], np.broadcast_to(rel, (c,) + rel.shape), fov, math.inf,
                            view.vfov_deg)                                       # [C, M]
            angle = _angle_between(yaws[:, None], bearing[None, :])                # [C, M]
            cost = cost + self.w_obstacle * np.sum(np.where(inside, 0.0, threat * angle), axis=1)
        if self.w_unseen > 0:
            stale = np.minimum((t - self.bin_last_seen) / self.stale_s, 1.0)
            pts = self._bin_dirs * (0.5 * float(view.range_m))
            cover = in_fov(yaws[:, None], np.broadcast_to(pts, (c,) + pts.shape), fov, view.range_m,
                           view.vfov_deg)                                        # [C, B]
            per_fov = max(1.0, min(fov, 360.0) / 360.0 * self.bin_azimuths.shape[0])
            cost = cost - self.w_unseen * (cover @ stale) / per_fov
        return cost

    def _belief_at(self, angles_deg: np.ndarray) -> np.ndarray:
        """U at ``angles_deg`` (deg): the nearest bin's belief, the first bin on ties (the program's argmin)."""
        centres = np.arange(self.belief.shape[0]) * (360.0 / self.belief.shape[0])
        diff = np.abs(centres[None, :] - np.mod(np.asarray(angles_deg, dtype=float), 360.0).reshape(-1, 1))
        return self.belief[np.argmin(np.minimum(diff, 360.0 - diff), axis=1)]

    def program_costs(self, view: View) -> np.ndarray | None:
        """The program's total cost of each candidate in ``self.rates`` (module docstring), after updating the
        direction beliefs U as the program did at each decision; None for a MAV at rest (the program's costs were
        NaN there). Angles in degrees as the program computed them; G in rad^2."""
        half = float(view.fov_deg) / 2.0
        vel = np.asarray(view.velocity[:2], dtype=float)
        pos = np.asarray(view.position[:2], dtype=float)
        yaw_deg = math.degrees(float(view.yaw))
        n = self.belief.shape[0]
        centres = np.arange(n) * (360.0 / n)
        d_hat = np.stack([np.cos(np.radians(centres)), np.sin(np.radians(centres))], axis=1)
        dyaw = np.abs(np.mod(centres - yaw_deg, 360.0))
        seen = np.minimum(dyaw, 360.0 - dyaw) < half
        gain = -(d_hat @ (vel * self.period_s)) / float(view.range_m) + np.where(seen, 0.4, -0.05)
        self.belief = np.clip(self.belief + gain, 0.0, 1.0)
        speed = float(np.hypot(vel[0], vel[1]))
        if speed == 0.0:
            return None
        yaws = yaw_deg + np.degrees(self.rates) * self.period_s                 # deg, [C]

        def g(theta):
            a = np.abs(np.mod(theta, 360.0))
            a = np.minimum(a, 360.0 - a)
            e1 = np.abs(np.mod(theta - half, 360.0))
            e2 = np.abs(np.mod(theta + half, 360.0))
            prod = np.radians(np.minimum(e1, 360.0 - e1)) * np.radians(np.minimum(e2, 360.0 - e2))
            return np.where(a <= half, 0.0, prod)

        to_goal = np.asarray(view.goal[:2], dtype=float) - pos
        d_g = math.degrees(math.atan2(to_goal[1], to_goal[0]))
        d_v = math.degrees(math.atan2(vel[1] / speed, vel[0] / speed))
        cost = self.w_goal * g(yaws - d_g) * (1.0 - self._belief_at(np.array([d_g]))[0])
        cost = cost + self.w_velocity * speed * speed * g(yaws - d_v) * (1.0 - self._belief_at(np.array([d_v]))[0])
        tracks = view.tracks
        if len(tracks) and self.w_obstacle > 0:
            rel = tracks.position[:, :2] - pos
            d_o = np.degrees(np.arctan2(rel[:, 1], rel[:, 0]))                  # [M], active tracks by id
            k = np.arange(len(tracks))
            weight = np.zeros(len(tracks))
            pair = np.searchsorted(tracks.ids, k)                                # track of obstacle k, if active
            has = (pair < len(tracks)) & (tracks.ids[np.minimum(pair, len(tracks) - 1)] == k)
            j = pair[has]
            dist = np.hypot(rel[j, 0], rel[j, 1])
            weight[has] = np.hypot(tracks.velocity[j, 0], tracks.velocity[j, 1]) / np.maximum(dist, 1e-12)
            cost = cost + self.w_obstacle * np.sum(weight[None, :] * g(yaws[:, None] - d_o[None, :]), axis=1)
        cost = cost + self.w_unseen * self._belief_at(yaws)
        return cost + self.w_rate * np.abs(self.rates * self.period_s)

    def _program_rate(self, view: View) -> float:
        if self._steps_left <= 0:
            cost = self.program_costs(view)
            self.last_costs = cost
            idx = 0 if cost is None else int(np.argmin(cost))
            self.held_rate = float(self.rates[idx])
            self._steps_left = self.hold_steps
        self._steps_left -= 1
        return self.held_rate

    def yaw_rate(self, view: View, trajectory: Trajectory | None) -> float:
        """The held rate (rad/s); a new one is chosen when period_s has passed since the last decision."""
        if self.costs_rule == "program":
            return self._program_rate(view)
        self._observe(view)
        t = float(view.t)
        if t + 1e-9 >= self._next_decision:
            cost = self.costs(view)
            self.last_costs = cost
            self.held_rate = float(self.rates[self._order[int(np.argmin(cost[self._order]))]])
            self._next_decision = t + self.period_s
        return self.held_rate
