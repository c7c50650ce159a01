"""The pieces the trials of a batch evaluate together (pbdyn.sim.batch: tracker bank, swept obstacle checks) give,
bit for bit, what each trial's own evaluation gives."""

from __future__ import annotations

import numpy as np
import pytest

from pbdyn.perception.tracker import KalmanTracks, TrackerBank, TrackIdError
from pbdyn.sim.collision import swept_dynamic, swept_dynamic_many


def _tracker(rule: str, n: int = 12, dims: int = 2) -> KalmanTracks:
    hi = [50.0, 50.0, 20.0][:dims]
    return KalmanTracks(n, dims, 0.1, q=1e-4, r=0.01 if rule == "arena" else 0.0, bounds_lo=np.zeros(dims),
                        bounds_hi=np.asarray(hi), drop_rule=rule, nominal_radius=0.5, drop_pos_var=0.05)


def _detections(rng, n: int, dims: int, t: int):
    """Random distinct ids with noisy centres drifting out of the arena now and then (drops happen)."""
    ids = np.sort(rng.choice(n, size=int(rng.integers(0, n + 1)), replace=False))
    centre = np.stack([np.full(dims, 2.0 + 4.0 * i) for i in ids]).reshape(-1, dims) if ids.size else np.zeros((0, dims))
    z = centre + 0.3 * t * rng.normal(size=(ids.size, dims)) * (ids % 3 == 0)[:, None] + rng.normal(size=centre.shape)
    return ids, z


@pytest.mark.parametrize("rule", ["arena", "program"])
@pytest.mark.parametrize("dims", [2, 3])
def test_tracker_bank_steps_exactly_like_each_tracker_alone(rule, dims):
    rng = np.random.default_rng(7)
    n_trackers, n = 6, 12
    alone = [_tracker(rule, n, dims) for _ in range(n_trackers)]
    banked = [_tracker(rule, n, dims) for _ in range(n_trackers)]
    bank = TrackerBank(banked[0], n_trackers)
    rows = {}
    for step in range(60):
        if step % 10 == 0 and step // 10 < n_trackers:      # trackers join the bank at different times
            i = step // 10
            rows[i] = bank.attach(banked[i])
        live = sorted(rows)
        dets = [_detections(rng, n, dims, step) for _ in live]
        for i, (ids, z) in zip(live, dets):
            alone[i].step(ids, z)
        bank.step([rows[i] for i in live], [banked[i] for i in live], [d[0] for d in dets], [d[1] for d in dets])
        for i in live:
            a, b = alone[i], banked[i]
            assert np.array_equal(a.active, b.active) and np.array_equal(a.ever, b.ever)
            assert np.array_equal(a.x, b.x) and np.array_equal(a.P, b.P)
            assert a.tracked_time_s == b.tracked_time_s
            ta, tb = a.tracks(np.full(n, 0.7)), b.tracks(np.full(n, 0.7))
            assert np.array_equal(ta.ids, tb.ids) and np.array_equal(ta.radius, tb.radius)
        radii = [rng.uniform(0.3, 1.5, n) for _ in live]              # the bank's read-out of every tracker at once
        for i, r, got in zip(live, radii, bank.read_tracks([rows[i] for i in live], radii)):
            want = alone[i].tracks(r)
            for name in ("ids", "position", "velocity", "covariance", "radius"):
                x, y = getattr(got, name), getattr(want, name)
                assert x.dtype == y.dtype and np.array_equal(x, y) and not x.flags.writeable
                assert x.flags.c_contiguous and not np.shares_memory(x, bank.x) and not np.shares_memory(x, bank.P)
    drops = sum(int(t.ever.sum()) for t in alone)
    assert drops > 0 and any(t.n_active < t.ever_tracked for t in alone)   # tracks were started and dropped


def test_tracker_bank_refuses_bad_ids_before_changing_anything_and_other_models():
    trackers = [_tracker("arena") for _ in range(2)]
    bank = TrackerBank(trackers[0], 2)
    rows = [bank.attach(t) for t in trackers]
    bank.step(rows, trackers, [np.array([1, 2]), np.array([3])], [np.ones((2, 2)), np.ones((1, 2))])
    before = bank.x.copy(), bank.P.copy(), bank.active.copy()
    with pytest.raises(TrackIdError):
        bank.step(rows, trackers, [np.array([1, 1]), np.array([3])], [np.ones((2, 2)), np.ones((1, 2))])
    with pytest.raises(TrackIdError):
        bank.step(rows, trackers, [np.array([12]), np.array([3])], [np.ones((1, 2)), np.ones((1, 2))])
    assert all(np.array_equal(a, b) for a, b in zip(before, (bank.x, bank.P, bank.active)))
    assert bank.attach(_tracker("arena")) is None                          # full
    assert TrackerBank(trackers[0], 3).attach(_tracker("program")) is None  # another model


def test_swept_dynamic_many_equals_swept_dynamic_per_mav():
    rng = np.random.default_rng(3)
    hits = []
    for dims in (2, 3):
        for _ in range(40):
            n = int(rng.integers(0, 15))
            obs0 = rng.uniform(0, 20, (n, dims))
            obs1 = obs0 + rng.normal(0, 0.5, (n, dims))
            radii = rng.uniform(0.3, 1.5, n)
            m0 = rng.uniform(0, 20, (9, dims))
            m1 = m0 + rng.normal(0, 0.6, (9, dims))
            m1[0] = m0[0]                                                  # a MAV at rest
            got = swept_dynamic_many(m0, m1, obs0, obs1, radii, 1.0)
            want = [swept_dynamic(m0[i], m1[i], obs0, obs1, radii, 1.0) for i in range(9)]
            assert got == want
            hits += [c.hit for c in got]
    assert any(hits) and not all(hits)
