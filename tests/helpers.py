"""Test helpers: hand-built rollouts for scenario-level tests."""

from __future__ import annotations

import numpy as np

from pbdyn.config import Scenario
from pbdyn.world.maps import enumerate_maps, static_bodies
from pbdyn.world.motion import cvm_fold
from pbdyn.world.rollout import Rollout, default_horizon


def handmade_rollout(scenario: Scenario, p0, v0, radii) -> Rollout:
    """A CVM rollout of the given obstacles (centres [N, d], velocities [N, d], radii [N]) in the scenario's arena."""
    dt = scenario.world.dt
    n_t = int(round(default_horizon(scenario) / dt)) + 1
    times = np.arange(n_t) * dt
    p0 = np.asarray(p0, float).reshape(-1, scenario.world.dims)
    v0 = np.asarray(v0, float).reshape(-1, scenario.world.dims)
    radii = np.asarray(radii, float).reshape(-1)
    pos, vel = cvm_fold(p0, v0, radii, np.asarray(scenario.world.size), times)
    return Rollout(times, pos, vel, radii, np.asarray(scenario.world.size, float), dt, static_bodies(scenario),
                   {"handmade": True})


def first_map(scenario: Scenario):
    """The scenario's map 0."""
    return enumerate_maps(scenario)[0]
