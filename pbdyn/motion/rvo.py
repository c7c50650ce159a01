"""The RVO obstacle motion model, ``obstacles.motion = "rvo"``: optimal reciprocal collision avoidance (ORCA) among
obstacles (thesis 2-3, fig. 2-3b; docs/scenarios.md "RVO"). Its parameters are the table ``[obstacles.rvo]``
(RVOParams).

Obstacles avoid each other reciprocally and never the MAV, so an RVO map is still a deterministic rollout. Each step,
for every obstacle i and neighbour j the truncated velocity obstacle VO_ij (time horizon tau) yields an ORCA
half-plane (2D) / half-space (3D) {v : n_ij . (v - (v_i + u_ij / 2)) >= 0}, where u_ij is the smallest change of the
relative velocity that leaves VO_ij and n_ij the outward normal there (van den Berg et al., ORCA). Walls add
half-planes v_k >= -D_k / tau_w (D_k: gap to the wall). Then, vectorised over [obstacles x candidate velocities],
every obstacle takes the admissible candidate closest to its preferred velocity, else the candidate whose largest
violation is smallest; ties go to the lower candidate index.

Candidates: the preferred velocity itself (so a lone obstacle keeps its CVM path exactly), zero, and
``n_headings`` directions x ``n_speeds`` speeds (k / n_speeds of the obstacle's own speed, k = 1..n_speeds).
2D: 32 headings x 6 speeds (the thesis program's set). 3D: ``n_headings`` directions on a Fibonacci sphere
(default 64) x 6 speeds.

Preferred velocity = the obstacle's CVM velocity, reflected at the walls: positions are integrated explicitly and
folded back specularly at the walls (exactly as the CVM fold), and a fold on an axis points the preferred
velocity's component on that axis away from that wall.

Wall horizon: tau_w defaults to one step (dt) and walls are skipped for an obstacle whose own preferred motion
reflects there within the step: an obstacle reaches a wall at full speed and reflects like a CVM obstacle. A longer
tau_w (e.g. 2 s) makes obstacles slow down |v| tau_w before every wall, so a lone obstacle would no longer follow
its CVM path; it is available as a parameter.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from pbdyn import limits
from pbdyn.motion.protocol import TableKey


@dataclass(frozen=True)
class RVOParams:
    """ORCA parameters (``[obstacles.rvo]``): time_horizon tau (s) for neighbours, wall_time_horizon tau_w (s;
    None = dt), candidate set n_headings (None: N_HEADINGS_2D / N_HEADINGS_3D) x n_speeds, neighbour_dist (m, pairs
    farther apart than this between surfaces are ignored; None = tau * (v_i + v_j) + 1 m; not a scenario key),
    contact_iterations (0 disables the last-resort contact step). A scenario keeps them as
    pbdyn.config.ObstacleConfig.rvo."""

    N_HEADINGS_2D: ClassVar[int] = 32
    N_HEADINGS_3D: ClassVar[int] = 64

    time_horizon: float = 2.0
    wall_time_horizon: float | None = None
    n_headings: int | None = None
    n_speeds: int = 6
    neighbour_dist: float | None = None
    contact_iterations: int = 4


def candidate_directions(dims: int, n: int) -> np.ndarray:
    """Unit directions [n, d]: 2D headings 2 pi k / n; 3D a Fibonacci lattice on the sphere."""
    k = np.arange(n)
    if dims == 2:
        ang = 2.0 * np.pi * k / n
        return np.stack([np.cos(ang), np.sin(ang)], axis=1)
    z = 1.0 - (2.0 * k + 1.0) / n
    rho = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    phi = k * np.pi * (3.0 - np.sqrt(5.0))
    return np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=1)


def _perpendicular(e1: np.ndarray) -> np.ndarray:
    """A unit vector perpendicular to each row of e1 [..., d] (deterministic)."""
    if e1.shape[-1] == 2:
        return np.stack([-e1[..., 1], e1[..., 0]], axis=-1)
    axis = np.zeros_like(e1)
    idx = np.argmin(np.abs(e1), axis=-1)
    np.put_along_axis(axis, idx[..., None], 1.0, axis=-1)
    w = np.cross(e1, axis)
    norm = np.linalg.norm(w, axis=-1, keepdims=True)
    return w / np.where(norm > 0.0, norm, 1.0)


def orca_halfspaces(pos: np.ndarray, vel: np.ndarray, radii: np.ndarray, tau: float,
                    dt: float) -> tuple[np.ndarray, np.ndarray]:
    """ORCA constraints of every obstacle i against every other j (van den Berg et al.; thesis 2-3 RVO).

    Args:
        pos, vel: centres [N, d] (m) and current velocities [N, d] (m/s); radii [N] (m); tau: horizon (s);
        dt: step (s), used for pairs that already overlap.
    Returns:
        normals [N, N, d] (unit) and offsets [N, N] (m/s): obstacle i must satisfy normals[i, j] . v >= offsets[i, j]
        (= n . (v_i + u / 2)); the diagonal is a void constraint (zero normal, offset -inf).
    """
    n, d = pos.shape
    p = pos[None, :, :] - pos[:, None, :]                         # [i, j]: p_j - p_i
    v = vel[:, None, :] - vel[None, :, :]                         # v_i - v_j
    big_r = radii[:, None] + radii[None, :]
    dist = np.linalg.norm(p, axis=-1)
    eye = np.eye(n, dtype=bool)
    safe_dist = np.where(eye | (dist == 0.0), 1.0, dist)
    e1 = p / safe_dist[..., None]
    e1[eye | (dist == 0.0)] = 0.0
    e1[(dist == 0.0) & ~eye, 0] = 1.0                              # coincident centres: any axis
    a = np.einsum("ijk,ijk->ij", v, e1)
    perp = v - a[..., None] * e1
    b = np.linalg.norm(perp, axis=-1)
    e2 = np.where((b > 1e-12)[..., None], perp / np.where(b > 1e-12, b, 1.0)[..., None], _perpendicular(e1))

    colliding = dist <= big_r
    # --- separated pairs: closest point on the truncated cone's boundary, in the (e1, e2) half-plane ----------
    sin_a = np.clip(big_r / safe_dist, 0.0, 1.0)
    cos_a = np.sqrt(np.maximum(1.0 - sin_a * sin_a, 0.0))
    leg_len = np.sqrt(np.maximum(dist * dist - big_r * big_r, 0.0)) / tau
    s = a * cos_a + b * sin_a                                      # projection on the upper leg
    s_leg = np.maximum(s, leg_len)
    leg_x, leg_y = s_leg * cos_a, s_leg * sin_a
    d_leg = np.hypot(leg_x - a, leg_y - b)
    cx, rho = dist / tau, big_r / tau
    wx, wy = a - cx, b
    wn = np.hypot(wx, wy)
    ux_unit = np.where(wn > 1e-12, wx / np.where(wn > 1e-12, wn, 1.0), -1.0)
    uy_unit = np.where(wn > 1e-12, wy / np.where(wn > 1e-12, wn, 1.0), 0.0)
    on_arc = ux_unit <= -sin_a
    arc_x, arc_y = cx + rho * ux_unit, rho * uy_unit
    d_arc = np.where(on_arc, np.hypot(arc_x - a, arc_y - b), np.inf)
    use_arc = d_arc < d_leg
    bx = np.where(use_arc, arc_x, leg_x)
    by = np.where(use_arc, arc_y, leg_y)
    nx = np.where(use_arc, ux_unit, -sin_a)
    ny = np.where(use_arc, uy_unit, cos_a)
    u = (bx - a)[..., None] * e1 + (by - b)[..., None] * e2
    normal = nx[..., None] * e1 + ny[..., None] * e2

    # --- overlapping pairs: leave the overlap within one step ---------------------------------------------------
    if np.any(colliding & ~eye):
        w = v - p / dt
        wl = np.linalg.norm(w, axis=-1)
        wu = np.where((wl > 1e-12)[..., None], w / np.where(wl > 1e-12, wl, 1.0)[..., None], -e1)
        u_c = (big_r / dt - wl)[..., None] * wu
        sel = colliding[..., None]
        u = np.where(sel, u_c, u)
        normal = np.where(sel, wu, normal)

    offsets = np.einsum("ijk,ijk->ij", normal, vel[:, None, :] + 0.5 * u)
    normal[eye] = 0.0
    offsets[eye] = -np.inf
    return normal, offsets


def _after_fold(pos: np.ndarray, vel: np.ndarray, lo: np.ndarray, hi: np.ndarray, dt: float) -> np.ndarray:
    """Velocities [..., d] with the components flipped that would carry pos across a wall within dt."""
    nxt = pos + vel * dt
    return np.where((nxt < lo) | (nxt > hi), -vel, vel)


def _worst_violation(cands, pos, lo, hi, dt, normal, offset, w_lo, w_hi) -> np.ndarray:
    """Largest constraint violation (m/s, <= 0 means admissible) of candidate velocities cands [B, M, d] of
    obstacles at pos [B, d]: ORCA rows normal [B, N, d] . v >= offset [B, N] on the wall-folded velocity, and the
    wall bounds w_lo <= v <= w_hi [B, d]."""
    eff = _after_fold(pos[:, None, :], cands, lo[:, None, :], hi[:, None, :], dt)
    worst = (offset[:, None, :] - np.matmul(eff, normal.transpose(0, 2, 1))).max(axis=2)
    wall = np.maximum(w_lo[:, None, :] - cands, cands - w_hi[:, None, :]).max(axis=2)
    return np.maximum(worst, wall)


def _separate(pos: np.ndarray, radii: np.ndarray, lo: np.ndarray, hi: np.ndarray, iterations: int) -> np.ndarray:
    """Last-resort contact step: push overlapping pairs apart along their centre line, half each (Jacobi
    iterations), then clip into the arena. A no-op when nothing overlaps."""
    if iterations <= 0 or pos.shape[0] < 2:
        return pos
    reach = radii[:, None] + radii[None, :]
    for _ in range(iterations):
        rel = pos[:, None, :] - pos[None, :, :]                       # [i, j]: p_i - p_j
        dist = np.linalg.norm(rel, axis=-1)
        np.fill_diagonal(dist, np.inf)
        pen = reach - dist
        if not np.any(pen > 0.0):
            break
        pen = np.where(pen > 0.0, pen, 0.0)
        unit = rel / np.where(np.isfinite(dist) & (dist > 0), dist, 1.0)[..., None]
        pos = np.clip(pos + 0.5 * np.einsum("ij,ijk->ik", pen, unit), lo, hi)
    return pos


def rvo_rollout(p0: np.ndarray, v0: np.ndarray, radii: np.ndarray, size: np.ndarray, dt: float, n_steps: int,
                params: RVOParams = RVOParams()) -> tuple[np.ndarray, np.ndarray]:
    """Integrate ORCA obstacle motion for n_steps steps of dt (s) from centres p0 [N, d] and CVM velocities v0.

    Returns positions [n_steps, N, d] (m) and executed velocities [n_steps, N, d] (m/s); step 0 is the initial state.
    Positions stay in [r, L - r] on every axis (specular fold at the walls).
    """
    pos = np.array(p0, dtype=float)
    n, d = pos.shape
    radii = np.asarray(radii, dtype=float)
    size = np.asarray(size, dtype=float)
    lo = radii[:, None] * np.ones(d)
    hi = size[None, :] - radii[:, None]
    pref = np.array(v0, dtype=float)
    vel = pref.copy()
    speed = np.linalg.norm(pref, axis=1)
    n_head = params.n_headings or (params.N_HEADINGS_2D if d == 2 else params.N_HEADINGS_3D)
    dirs = candidate_directions(d, n_head)
    fracs = np.arange(1, params.n_speeds + 1) / params.n_speeds
    unit_cands = (fracs[None, :, None] * dirs[:, None, :]).reshape(-1, d)          # [Mu, d], times each speed
    tau = float(params.time_horizon)
    tau_w = float(params.wall_time_horizon) if params.wall_time_horizon else dt
    out_p = np.empty((n_steps, n, d))
    out_v = np.empty((n_steps, n, d))
    out_p[0], out_v[0] = pos, vel
    if n == 0:
        return out_p, out_v
    for k in range(1, n_steps):
        # a velocity that crosses a wall within the step is reflected there: judge every velocity by the one the
        # obstacle will really have (the current ones for the ORCA geometry, each candidate for the choice)
        normal, offset = orca_halfspaces(pos, _after_fold(pos, vel, lo, hi, dt), radii, tau, dt)
        gap = np.linalg.norm(pos[None] - pos[:, None], axis=-1) - (radii[:, None] + radii[None, :])
        reach = (params.neighbour_dist if params.neighbour_dist is not None
                 else tau * (speed[:, None] + speed[None, :]) + 1.0)
        offset = np.where(gap <= reach, offset, -np.inf)
        # walls: v_k >= -(x_k - lo)/tau_w and v_k <= (hi - x_k)/tau_w, except where the preferred motion reflects
        nxt = pos + pref * dt
        w_lo = np.where(nxt < lo, -np.inf, -(pos - lo) / tau_w)                  # [N, d]
        w_hi = np.where(nxt > hi, np.inf, (hi - pos) / tau_w)
        vel = pref.copy()
        # candidate 0 is the preferred velocity (cost 0): where it is admissible it is the choice, so only the
        # other obstacles need the whole candidate set (same result as evaluating all, far less work)
        worst0 = _worst_violation(pref[:, None, :], pos, lo, hi, dt, normal, offset, w_lo, w_hi)[:, 0]
        busy = np.flatnonzero(worst0 > 1e-12)
        if busy.size:
            cands = np.concatenate([pref[busy, None, :], np.zeros((busy.size, 1, d)),
                                    speed[busy, None, None] * unit_cands[None]], axis=1)       # [B, M, d]
            # a row n . v >= b binds some |v| <= s only if b > -s: keep just those neighbours (the rest hold for
            # every candidate), gathered into the K columns that matter
            off_b = offset[busy]
            live = off_b > -(speed[busy, None] + 1e-9)
            k_live = max(int(live.sum(axis=1).max()), 1)
            cols = np.argsort(np.where(live, -off_b, np.inf), axis=1, kind="stable")[:, :k_live]
            rows = np.arange(busy.size)[:, None]
            worst = _worst_violation(cands, pos[busy], lo[busy], hi[busy], dt, normal[busy[:, None], cols],
                                     np.where(live[rows, cols], off_b[rows, cols], -np.inf), w_lo[busy], w_hi[busy])
            admissible = worst <= 1e-12
            diff = cands - pref[busy, None, :]
            cost = np.where(admissible, np.einsum("imk,imk->im", diff, diff), np.inf)
            best = np.where(admissible.any(axis=1), np.argmin(cost, axis=1), np.argmin(worst, axis=1))
            vel[busy] = cands[np.arange(busy.size), best]
        new = pos + vel * dt
        below = (new < lo) | ((new == lo) & (vel < 0.0))  # on the wall: reflected, as the CVM fold
        above = (new > hi) | ((new == hi) & (vel > 0.0))
        new = np.where(below, 2.0 * lo - new, np.where(above, 2.0 * hi - new, new))
        new = np.clip(new, lo, hi)
        vel = np.where(below | above, -vel, vel)
        pushed = _separate(new, radii, lo, hi, params.contact_iterations)
        vel = vel + (pushed - new) / dt
        pos = pushed
        pref = np.where(below, np.abs(pref), np.where(above, -np.abs(pref), pref))
        out_p[k], out_v[k] = pos, vel
    return out_p, out_v


class RVO:
    """The "rvo" model (pbdyn.motion.protocol.MotionModel): params = obstacles.rvo (RVOParams, from the table
    ``[obstacles.rvo]``); velocities are the executed ones (sample k: the velocity that moved the obstacle from
    t_k-1 to t_k, sign-flipped where it reflected at a wall; sample 0: v0)."""

    name = "rvo"
    table: str | None = "rvo"
    params_type: type | None = RVOParams
    table_keys: tuple[TableKey, ...] = (
        TableKey("time_horizon", False, 0.0, True), TableKey("wall_time_horizon", False, 0.0, True),
        TableKey("n_headings", True, 4), TableKey("n_speeds", True, 1), TableKey("contact_iterations", True, 0))

    def params(self, obstacles: Any) -> RVOParams:
        """obstacles.rvo."""
        return obstacles.rvo

    def check_params(self, params: RVOParams, given: Mapping[str, Any], where: str) -> None:
        """The candidate set (n_headings x n_speeds; an unset n_headings counts as the larger default) and the
        contact iterations within pbdyn.limits (MAX_RVO_CANDIDATES, MAX_RVO_CONTACT_ITERATIONS)."""
        n_head = params.n_headings or max(RVOParams.N_HEADINGS_2D, RVOParams.N_HEADINGS_3D)
        limits.check_limit(f"{where}.n_headings" if "n_headings" in given else f"{where}.n_speeds",
                           "candidate velocities per obstacle (n_headings x n_speeds)", n_head * params.n_speeds,
                           limits.MAX_RVO_CANDIDATES, params.n_headings if "n_headings" in given else params.n_speeds)
        limits.check_limit(f"{where}.contact_iterations", "contact iterations", params.contact_iterations,
                           limits.MAX_RVO_CONTACT_ITERATIONS, params.contact_iterations)

    def key_params(self, obstacles: Any) -> dict:
        """{"rvo": every RVOParams field}."""
        return {"rvo": vars(obstacles.rvo)}

    def rollout(self, p0: np.ndarray, v0: np.ndarray, radii: np.ndarray, size: np.ndarray, times: np.ndarray,
                dt: float, params: RVOParams) -> tuple[np.ndarray, np.ndarray]:
        """rvo_rollout over len(times) samples of dt (arguments: MotionModel.rollout)."""
        return rvo_rollout(p0, v0, radii, size, dt, times.shape[0], params)
