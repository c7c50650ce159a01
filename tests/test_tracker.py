"""KalmanTracks against filterpy's KalmanFilter (one filter per obstacle), dropping rule, convergence."""

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter

from pbdyn.perception.tracker import KalmanTracks

DT = 0.1
LO, HI = 0.0, 50.0


def _reference_filter(dims, q, r, p0_pos, p0_vel, z):
    kf = KalmanFilter(dim_x=2 * dims, dim_z=dims)
    eye = np.eye(dims)
    kf.F = np.block([[eye, DT * eye], [np.zeros((dims, dims)), eye]])
    kf.H = np.hstack([eye, np.zeros((dims, dims))])
    kf.Q = q * np.eye(2 * dims)
    kf.R = r * eye
    kf.P = np.diag(np.r_[np.full(dims, p0_pos), np.full(dims, p0_vel)])
    kf.x = np.r_[z, np.zeros(dims)].reshape(-1, 1)
    return kf


@pytest.mark.parametrize("dims,r", [(2, 0.0), (3, 0.0), (2, 0.04), (3, 0.25)])
def test_matches_filterpy_with_intermittent_detections(dims, r):
    rng = np.random.default_rng(7 + dims)
    n, steps, q, p0_pos, p0_vel = 6, 120, 1e-5, 0.01, 0.1
    pos = rng.uniform(15, 35, (n, dims))
    vel = rng.uniform(-1.0, 1.0, (n, dims))
    tr = KalmanTracks(n, dims, DT, q=q, r=r, p0_pos=p0_pos, p0_vel=p0_vel, drop_pos_var=1e9,
                      bounds_lo=np.full(dims, -1e6), bounds_hi=np.full(dims, 1e6))
    ref: dict[int, KalmanFilter] = {}
    n_updates = 0
    for _ in range(steps):
        pos = pos + DT * vel
        seen = np.flatnonzero(rng.random(n) < 0.4)
        z = pos[seen] + (rng.normal(0, np.sqrt(r), (seen.size, dims)) if r > 0 else 0.0)
        for kf in ref.values():
            kf.predict()
        for i, zi in zip(seen, z):
            if int(i) in ref:
                ref[int(i)].update(zi)
                n_updates += 1
            else:
                ref[int(i)] = _reference_filter(dims, q, r, p0_pos, p0_vel, zi)
        tr.step(seen, z)
        tracks = tr.tracks(np.arange(n) * 0.1 + 0.5)
        assert list(tracks.ids) == sorted(ref)
        for k, i in enumerate(tracks.ids):
            kf = ref[int(i)]
            np.testing.assert_allclose(tracks.position[k], kf.x[:dims, 0], rtol=0, atol=1e-10)
            np.testing.assert_allclose(tracks.velocity[k], kf.x[dims:, 0], rtol=0, atol=1e-10)
            np.testing.assert_allclose(tracks.covariance[k], kf.P, rtol=0, atol=1e-10)
            assert tracks.radius[k] == pytest.approx(0.5 + 0.1 * i)
    assert n_updates > 100
    assert tr.ever_tracked == len(ref) == n


def test_new_track_starts_at_measurement_with_zero_velocity_and_is_not_updated():
    tr = KalmanTracks(3, 2, DT, bounds_lo=[LO, LO], bounds_hi=[HI, HI])
    tr.step([1], [[10.0, 20.0]])
    t = tr.tracks(np.ones(3))
    assert list(t.ids) == [1]
    np.testing.assert_array_equal(t.position, [[10.0, 20.0]])
    np.testing.assert_array_equal(t.velocity, [[0.0, 0.0]])
    np.testing.assert_array_equal(t.covariance[0], np.diag([0.01, 0.01, 0.1, 0.1]))


def test_velocity_converges_for_cvm_obstacle_seen_every_step():
    for dims in (2, 3):
        v_true = np.array([3.0, -2.0, 1.0][:dims])
        p = np.full(dims, 25.0)
        tr = KalmanTracks(1, dims, DT, bounds_lo=np.full(dims, LO), bounds_hi=np.full(dims, HI))
        for _ in range(60):
            p = p + DT * v_true
            tr.step([0], p[None])
        t = tr.tracks([1.0])
        np.testing.assert_allclose(t.velocity[0], v_true, atol=1e-3)
        np.testing.assert_allclose(t.position[0], p, atol=1e-6)


def test_drop_on_position_variance():
    tr = KalmanTracks(2, 2, DT, q=1e-3, drop_pos_var=0.05, bounds_lo=[LO, LO], bounds_hi=[HI, HI])
    tr.step([0, 1], [[10.0, 10.0], [30.0, 30.0]])
    steps = 0
    while tr.active[0]:
        tr.step([1], [[30.0, 30.0]])  # obstacle 0 unseen: its variance grows
        steps += 1
        var = np.diagonal(tr.P[0, :2, :2]).max()
        if tr.active[0]:
            assert var <= 0.05
        else:
            assert var > 0.05
        assert steps < 100
    assert steps > 1
    assert tr.active[1]
    assert list(tr.tracks(np.ones(2)).ids) == [1]
    # seen again after the drop: a fresh track with zero velocity and P0
    tr.step([0], [[11.0, 11.0]])
    np.testing.assert_array_equal(tr.x[0], [11.0, 11.0, 0.0, 0.0])
    np.testing.assert_array_equal(tr.P[0], tr.P0)
    assert tr.ever_tracked == 2


def test_drop_when_mean_leaves_arena_and_tracked_time():
    tr = KalmanTracks(2, 2, DT, bounds_lo=[LO, LO], bounds_hi=[HI, HI])
    x = 49.0
    tr.step([0, 1], [[x, 25.0], [25.0, 25.0]])
    for _ in range(5):  # obstacle 0 moves at +4 m/s in x and is seen every step
        x += 0.4
        tr.step([0, 1], [[x, 25.0], [25.0, 25.0]])
    assert not tr.active[0] and tr.active[1]
    # R = 0: the mean is the measurement; obstacle 0 is inside at x = 49.0, 49.4, 49.8 (3 steps), re-detections
    # outside the arena start tracks that are dropped at once; obstacle 1 is tracked for all 6 steps
    assert tr.tracked_time_s == pytest.approx(DT * (6 + 3))
    assert tr.ever_tracked == 2


def test_program_drop_rule_drops_a_predicted_disc_at_the_wall_and_restarts_a_step_later():
    """drop_rule = "program" (the thesis program's KalmanFilter): a track whose predicted mean is not strictly more
    than the setup radius from a wall is dropped before the update, that step's detection is discarded, the next
    detection restarts it (zero velocity) with the setup radius; so a resting obstacle 0.9 m from a wall (setup
    radius 1 m) flickers. The "arena" rule keeps it."""
    radii = np.array([0.8, 0.8])
    prog = KalmanTracks(2, 2, DT, bounds_lo=[LO, LO], bounds_hi=[48.0, 48.0], drop_rule="program",
                        nominal_radius=1.0)
    arena = KalmanTracks(2, 2, DT, bounds_lo=[LO, LO], bounds_hi=[48.0, 48.0])
    z = [[0.9, 24.0], [24.0, 24.0]]
    active, radius = [], []
    for _ in range(6):
        prog.step([0, 1], z)
        arena.step([0, 1], z)
        active.append(bool(prog.active[0]))
        radius.append(prog.tracks(radii).radius[0] if prog.active[0] else None)
        assert prog.active[1] and arena.active[0] and arena.active[1]
    assert active == [True, False, True, False, True, False]
    assert radius[0] == 0.8 and radius[2] == radius[4] == 1.0          # restarted tracks carry the setup radius
    np.testing.assert_array_equal(prog.x[1], arena.x[1])                # away from the walls both rules agree
    np.testing.assert_array_equal(prog.P[1], arena.P[1])
    assert prog.tracks(radii).radius[-1] == 0.8
    with pytest.raises(ValueError):
        KalmanTracks(1, 2, DT, bounds_lo=[LO, LO], bounds_hi=[HI, HI], drop_rule="never")


def test_setup_track_radius_reports_the_setup_radius_for_every_track():
    """track_radius = "setup": the program's planners, when it flew the thesis' trials, checked every track with the
    setup radius; "own" keeps each obstacle's radius (the setup radius only after a "program" restart)."""
    from pbdyn.perception.tracker import KalmanTracks
    kw = dict(bounds_lo=np.zeros(2), bounds_hi=np.full(2, 48.0), nominal_radius=1.0)
    radii = np.array([0.8, 1.2, 1.15])
    for rule, want in (("own", radii[[0, 2]]), ("setup", [1.0, 1.0])):
        tr = KalmanTracks(3, 2, 0.1, track_radius=rule, **kw)
        tr.update(np.array([0, 2]), np.array([[10.0, 10.0], [20.0, 20.0]]))
        np.testing.assert_array_equal(tr.tracks(radii).radius, want)
    with pytest.raises(ValueError, match="track_radius"):
        KalmanTracks(3, 2, 0.1, track_radius="mean", **kw)


def test_the_tracks_read_out_equals_tracks_built_field_by_field_and_is_read_only():
    """KalmanTracks.tracks (Tracks.of_owned: fresh copies made read-only, no dataclass __init__) gives what Tracks(...)
    gives; writing to it fails and the filter's own state is not shared."""
    from pbdyn.perception.tracks import Tracks

    tr = KalmanTracks(4, 2, DT, bounds_lo=np.full(2, LO), bounds_hi=np.full(2, HI))
    tr.step(np.array([1, 3]), np.array([[10.0, 10.0], [20.0, 30.0]]))
    tr.step(np.array([1, 3]), np.array([[10.1, 10.0], [20.0, 30.2]]))
    radii = np.array([0.5, 0.8, 1.0, 1.2])
    got = tr.tracks(radii)
    idx = np.flatnonzero(tr.active)
    want = Tracks(idx, tr.x[idx, :2], tr.x[idx, 2:], tr.P[idx], radii[idx])
    assert type(got) is Tracks and len(got) == 2
    for name in ("ids", "position", "velocity", "covariance", "radius"):
        a, b = getattr(got, name), getattr(want, name)
        assert a.dtype == b.dtype and np.array_equal(a, b) and not a.flags.writeable
        assert not np.shares_memory(a, tr.x) and not np.shares_memory(a, tr.P)
    with pytest.raises(ValueError):
        got.position[0, 0] = 1.0
