"""The compiled candidate kernels against numpy's evaluation of the same expressions (the reference), bit for bit."""

import warnings
from fractions import Fraction

import numpy as np
import pytest

from pbdyn.perception.grid import OccupancyGrid
from pbdyn.perception.tracks import Tracks
from pbdyn.planning.primitives.compiled.candidate_kernels import fma, numpy_orders, peaks, world_and_screen
from pbdyn.planning.checks import WALL_MARGIN_CAP, _track_hits, _wall_hits
from pbdyn.planning.view import MAVLimits, View

DT = 0.1


def test_fma_rounds_once():
    rng = np.random.default_rng(3)
    for a, b, c in rng.normal(size=(500, 3)) * 10.0 ** rng.integers(-6, 6, size=(500, 3)):
        assert fma(a, b, c) == float(Fraction(a) * Fraction(b) + Fraction(c))


@pytest.mark.parametrize("d", [2, 3])
def test_numpy_orders_are_known_here(d):
    with warnings.catch_warnings():
        warnings.simplefilter("error")                 # an unknown order warns: the kernels would not match numpy
        assert numpy_orders.__wrapped__(d) == numpy_orders(d)


def _samples(rng, n, d):
    counts = rng.integers(2, 25, size=n).astype(np.int64)
    s = rng.normal(size=(n, counts.max(), 3, d)) * rng.uniform(0.1, 5.0, size=(n, 1, 3, 1))
    for c, k in enumerate(counts):
        s[c, k:] = 0.0
    return s, counts


def peaks_reference(samples, counts, dt):
    """The reference twin of peaks: the limit peaks as the planner computed them with numpy before they were
    compiled."""
    sq = np.einsum("nkij,nkij->nki", samples[:, 1:, 1:], samples[:, 1:, 1:]).max(axis=1)
    p, v = samples[:, :, 0], samples[:, :, 1]
    dv = v[:, 1:] - v[:, :-1]
    gap = p[:, 1:] - p[:, :-1] - 0.5 * (v[:, :-1] + v[:, 1:]) * dt
    dv2 = np.add.reduce(dv * dv, axis=2)
    gap2 = np.add.reduce(gap * gap, axis=2)
    pad = np.arange(dv2.shape[1])[None, :] >= (counts - 1)[:, None]
    dv2[pad] = 0.0
    gap2[pad] = 0.0
    step = np.maximum(np.sqrt(dv2.max(axis=1)) / dt, 4.0 * np.sqrt(gap2.max(axis=1)) / (dt * dt))
    return np.sqrt(sq[:, 0]), np.maximum(np.sqrt(sq[:, 1]), step)


@pytest.mark.parametrize("d", [2, 3])
def test_peaks_equal_numpy(d):
    rng = np.random.default_rng(d)
    samples, counts = _samples(rng, 300, d)
    v_peak, a_peak = peaks(samples, counts, DT, numpy_orders(d)[1])
    want_v, want_a = peaks_reference(samples, counts, DT)
    assert np.array_equal(v_peak, want_v) and np.array_equal(a_peak, want_a)


def _view(rng, d, n_tracks):
    lo, hi = np.zeros(d), np.full(d, 20.0)
    tracks = Tracks(ids=np.arange(n_tracks), position=rng.uniform(0, 20, size=(n_tracks, d)), velocity=rng.normal(size=(n_tracks, d)),
                    covariance=np.tile(np.eye(2 * d), (n_tracks, 1, 1)), radius=rng.uniform(0.3, 1.5, n_tracks))
    return View(t=3.7, dt=DT, position=rng.uniform(2, 18, d), velocity=rng.normal(size=d),
                acceleration=rng.normal(size=d), yaw=0.0, goal=np.full(d, 19.0), goal_radius=1.0,
                limits=MAVLimits(radius=0.3, v_max=4.0, a_max=4.0, yaw_rate=3.0), bounds_lo=lo, bounds_hi=hi,
                grid=OccupancyGrid(lo, hi, 1.0), tracks=tracks)


def world_and_screen_reference(view, frame, counts, bases, margin):
    """The reference twin of world_and_screen, as the planner evaluated it with numpy: the samples in the world frame
    [C, K, 3 (p, v, a), d] (sample 0 the view's state) and whether samples 1.. of each candidate meet a wall or a
    track's prediction [C] (pbdyn.planning.checks)."""
    world = frame @ bases[:, None]
    world[:, :, 0] += view.position
    world[:, 0] = view.position, view.velocity, view.acceleration
    bad = np.zeros(len(counts), dtype=bool)
    for c, k in enumerate(counts):
        times = view.t + DT * np.arange(k)
        hit = _wall_hits(view, world[c, 1:k, 0], margin).any()
        if len(view.tracks):
            hit |= _track_hits(view, world[c, 1:k, 0], times[1:] - view.t, margin).any()
        bad[c] = hit
    return world, bad


@pytest.mark.parametrize("d", [2, 3])
@pytest.mark.parametrize("n_tracks", [0, 6])
def test_world_and_screen_equal_numpy(d, n_tracks):
    rng = np.random.default_rng(10 * d + n_tracks)
    margin = 0.5
    mm_mode, sq_order = numpy_orders(d)
    n_hit = 0
    for _ in range(20):
        view = _view(rng, d, n_tracks)
        frame, counts = _samples(rng, 12, d)
        bases = np.linalg.qr(rng.normal(size=(12, d, d)))[0]
        wall_r = view.limits.radius + min(margin, WALL_MARGIN_CAP)
        reach = view.tracks.radius + (view.limits.radius + margin)
        p, v, a, bad = world_and_screen(frame, counts, bases, view.position, view.velocity, view.acceleration,
                                        view.bounds_lo + wall_r, view.bounds_hi - wall_r, view.tracks.position,
                                        view.tracks.velocity, reach * reach, view.t, DT, mm_mode, sq_order)
        world, want_bad = world_and_screen_reference(view, frame, counts, bases, margin)
        for c, k in enumerate(counts):
            assert np.array_equal(p[c, :k], world[c, :k, 0]) and np.array_equal(v[c, :k], world[c, :k, 1])
            assert np.array_equal(a[c, :k], world[c, :k, 2])
            assert bad[c] == want_bad[c]
            n_hit += int(want_bad[c])
    assert 0 < n_hit < 240                                                # both outcomes exercised
