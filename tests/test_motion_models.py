"""The obstacle motion registry (pbdyn/motion/registry.py): every model follows the protocol, and a model added to
MODELS alone is accepted by scenario validation, dispatched to by build_rollout and keyed by rollout_key."""

from __future__ import annotations

import numpy as np
import pytest

from pbdyn.config import parse_scenario
from pbdyn.errors import ConfigError
from pbdyn.motion import registry
from pbdyn.motion.protocol import MotionModel, TableKey
from pbdyn.world.maps import enumerate_maps
from pbdyn.world.rollout import build_rollout, rollout_key


def test_every_model_follows_the_protocol():
    members = [m for m in vars(MotionModel) if not m.startswith("_")] + list(MotionModel.__annotations__)
    for name, model in registry.MODELS.items():
        assert model.name == name
        assert all(hasattr(model, m) for m in members), name
        assert (model.table is None) == (model.params_type is None) == (model.table_keys == ())
        assert all(isinstance(k, TableKey) for k in model.table_keys)


class _Still:
    """A model of obstacles that never move (a test's own, registered only here)."""

    name = "still"
    table = None
    params_type = None
    table_keys = ()

    def params(self, obstacles):
        return None

    def check_params(self, params, given, where):
        pass

    def key_params(self, obstacles):
        return {"still": 1}

    def rollout(self, p0, v0, radii, size, times, dt, params):
        pos = np.broadcast_to(np.asarray(p0, float), (times.shape[0],) + np.shape(p0)).copy()
        return pos, np.zeros_like(pos)


def test_a_model_in_the_registry_alone_is_validated_dispatched_and_keyed(monkeypatch):
    doc = {"obstacles": {"count": 5, "motion": "still"}}
    with pytest.raises(ConfigError, match="obstacles.motion: must be one of cvm, rvo"):
        parse_scenario(doc)
    monkeypatch.setitem(registry.MODELS, "still", _Still())
    sc = parse_scenario(doc)
    spec = enumerate_maps(sc)[0]
    ro = build_rollout(sc, spec, 2.0)
    assert ro.meta["motion"] == "still" and np.array_equal(ro.positions[0], ro.positions[-1])
    assert not ro.velocities.any()
    cvm = parse_scenario({"obstacles": {"count": 5}})
    assert rollout_key(sc, spec, 2.0) != rollout_key(cvm, enumerate_maps(cvm)[0], 2.0)
    assert registry.key_params(sc.obstacles) == {"rvo": None, "still": 1}
    assert registry.key_params(cvm.obstacles) == {"rvo": None}


def test_a_model_table_is_refused_for_another_motion():
    with pytest.raises(ConfigError, match='obstacles.rvo: is only used with motion = "rvo"'):
        parse_scenario({"obstacles": {"rvo": {"time_horizon": 1.0}}})
    sc = parse_scenario({"obstacles": {"motion": "rvo", "rvo": {"n_speeds": 3}}})
    assert registry.key_params(sc.obstacles)["rvo"]["n_speeds"] == 3
