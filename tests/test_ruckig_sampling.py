"""The compiled ruckig sampler against ruckig itself (the reference), bit for bit."""

import math

import numpy as np
import pytest
import ruckig

from pbdyn.planning.primitives.compiled.ruckig_sampling import PROFILE_WIDTH, profile_row, sample_profiles

DT = 0.1


def _random_trajectories(d: int, n: int, seed: int):
    """(trajectory, sample count) of n random primitives like the planner's, some starting above the limits (a
    brake pre-phase), some ending at rest, some past their duration."""
    rng = np.random.default_rng(seed)
    otg = ruckig.Ruckig(d)
    inp = ruckig.InputParameter(d)
    out = []
    while len(out) < n:
        v_max = float(rng.choice([2.0, 4.0, 6.0]) * rng.uniform(0.5, 1.0))
        a_max = float(4.0 * rng.uniform(0.5, 1.0))
        inp.current_position = [0.0] * d
        inp.current_velocity = (rng.uniform(-1, 1, d) * v_max * rng.choice([0.8, 1.5])).tolist()
        inp.current_acceleration = (rng.uniform(-1, 1, d) * a_max * rng.choice([0.8, 1.5])).tolist()
        u = rng.normal(size=d)
        u /= np.linalg.norm(u)
        inp.target_position = (3.0 * u * rng.choice([1.0, rng.uniform(0.1, 1.0)])).tolist()
        inp.target_velocity = (0.5 * v_max * u * rng.choice([1.0, 0.0])).tolist()
        inp.target_acceleration = [0.0] * d
        inp.max_velocity = [v_max] * d
        inp.max_acceleration = [a_max] * d
        inp.max_jerk = [20.0] * d
        inp.minimum_duration = max(1.2 * 3.0 / v_max, 0.5)
        traj = ruckig.Trajectory(d)
        try:
            result = otg.calculate(inp, traj)
        except ruckig.RuckigError:
            continue
        if result not in (ruckig.Result.Working, ruckig.Result.Finished):
            continue
        k = max(2, math.ceil(traj.duration / DT - 1e-9) + 1) + int(rng.integers(0, 4))   # some samples past the end
        out.append((traj, k))
    return out


@pytest.mark.parametrize("d", [2, 3])
def test_samples_equal_ruckig_at_time_bit_for_bit(d):
    trajs = _random_trajectories(d, 600, seed=d)
    prof = np.array([profile_row(t) for t, _ in trajs]).reshape(len(trajs), d, PROFILE_WIDTH)
    assert (prof[:, :, 38] > 0).any(axis=1).sum() >= 50          # enough brake pre-phases to test them
    counts = np.array([k for _, k in trajs], dtype=np.int64)
    got = sample_profiles(prof, np.array([t.duration for t, _ in trajs]), counts, DT)
    assert got.shape == (len(trajs), counts.max(), 3, d)
    for c, (traj, k) in enumerate(trajs):
        want = np.array([traj.at_time(i * DT) for i in range(k)])               # [k, 3, d]
        assert np.array_equal(got[c, :k], want), c
        assert not got[c, k:].any()                                              # zero padding
