"""Sampling ruckig trajectories in compiled code (numba), bit for bit as ruckig's Trajectory.at_time.

Sampling a built trajectory through the Python binding costs one at_time call per sample (about 0.5 us each, ~9 us
for a typical primitive: most of a candidate's cost). Here the trajectory's per-axis profiles are read once
(profile_row) and all samples of a chunk of candidates are evaluated in one compiled loop (sample_profiles) with
ruckig's own arithmetic: the phase found by an upper bound on the cumulative phase times, then
p + t (v + t (a / 2 + t j / 6)), v + t (a + t j / 2), a + t j, the brake pre-phase first, and past the duration
the end state integrated with zero jerk. The reference is ruckig itself (tests/test_ruckig_sampling.py compares
both on random trajectories, with and without brake phases).

Layout of one axis' profile row (PROFILE_WIDTH floats): phase durations t[7], jerks j[7], phase start positions
p[8], velocities v[8], accelerations a[8], then the brake pre-phase: duration, t[2], j[2], p[2], v[2], a[2].
"""

from __future__ import annotations

import numpy as np

from pbdyn.jit import njit

PROFILE_WIDTH = 49
_T, _J, _P, _V, _A = 0, 7, 14, 22, 30
_BDUR, _BT, _BJ, _BP, _BV, _BA = 38, 39, 41, 43, 45, 47


_NO_BRAKE = [0.0] * 11


def profile_row(traj) -> list:
    """The profiles of a one-section ruckig Trajectory as a flat list [d * PROFILE_WIDTH] (module doc layout; an
    axis without a brake pre-phase gets zeros there, which sample_profiles never reads)."""
    flat: list = []
    for pr in traj.profiles[0]:
        flat += pr.t
        flat += pr.j
        flat += pr.p
        flat += pr.v
        flat += pr.a
        b = pr.brake
        if b.duration > 0.0:
            flat.append(b.duration)
            flat += b.t
            flat += b.j
            flat += b.p
            flat += b.v
            flat += b.a
        else:
            flat += _NO_BRAKE
    return flat


@njit(cache=True, nogil=True)
def sample_profiles(prof: np.ndarray, duration: np.ndarray, n_samples: np.ndarray, dt: float) -> np.ndarray:
    """Samples of C trajectories at times k dt, k = 0..n_samples[c]-1, as ruckig's at_time gives them.

    Args:
        prof: profile rows [C, d, PROFILE_WIDTH] (profile_row of each trajectory, reshaped).
        duration: the trajectories' durations [C] (s).
        n_samples: sample counts [C] (>= 1).
        dt: sample spacing (s).
    Returns:
        [C, max(n_samples), 3 (p, v, a), d] in the trajectories' own frame (m, m/s, m/s^2); zeros past a
        trajectory's last sample.
    """
    n_traj, d = prof.shape[0], prof.shape[1]
    if duration.shape[0] != n_traj or n_samples.shape[0] != n_traj or prof.shape[2] != PROFILE_WIDTH:
        raise ValueError("sample_profiles: mismatched shapes")
    out = np.zeros((n_traj, n_samples.max(), 3, d))
    t_sum = np.empty(7)
    for c in range(n_traj):
        sample_into(prof[c], duration[c], n_samples[c], dt, out[c], t_sum)
    return out


@njit(cache=True, nogil=True)
def sample_into(prof_c: np.ndarray, dur: float, n: int, dt: float, out_c: np.ndarray, t_sum: np.ndarray) -> None:
    """sample_profiles for one trajectory: its samples at k dt, k = 0..n-1, written to out_c[:n] ([>= n, 3, d]) from
    its profile rows prof_c [d, PROFILE_WIDTH] and duration ``dur`` (s); t_sum: scratch [7]."""
    d = prof_c.shape[0]
    for dof in range(d):
        r = prof_c[dof]
        acc = r[_T]
        t_sum[0] = acc
        for i in range(1, 7):
            acc = acc + r[_T + i]
            t_sum[i] = acc
        t_end = t_sum[6]
        b_dur = r[_BDUR]
        for k in range(n):
            time = k * dt
            if time >= dur:                      # past the end: the end state with zero jerk
                td = time - (b_dur + t_end)
                p0, v0, a0, jerk = r[_P + 7], r[_V + 7], r[_A + 7], 0.0
            else:
                td = time
                brake = False
                if b_dur > 0.0:
                    if td < b_dur:
                        brake = True
                    else:
                        td -= b_dur
                if brake:
                    i = 0
                    if td >= r[_BT]:
                        i = 1
                        td -= r[_BT]
                    p0, v0, a0, jerk = r[_BP + i], r[_BV + i], r[_BA + i], r[_BJ + i]
                elif td >= t_end:
                    td = td - t_end
                    p0, v0, a0, jerk = r[_P + 7], r[_V + 7], r[_A + 7], 0.0
                else:
                    i = 0
                    while i < 6 and t_sum[i] <= td:    # upper bound: the first phase ending after td
                        i += 1
                    if i > 0:
                        td -= t_sum[i - 1]
                    p0, v0, a0, jerk = r[_P + i], r[_V + i], r[_A + i], r[_J + i]
            out_c[k, 0, dof] = p0 + td * (v0 + td * (a0 / 2 + td * jerk / 6))
            out_c[k, 1, dof] = v0 + td * (a0 + td * jerk / 2)
            out_c[k, 2, dof] = a0 + td * jerk
