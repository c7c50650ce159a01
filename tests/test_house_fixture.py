"""Score cards and Gymnasium episodes fly bit for bit as recorded before the house round (tests/house_fixture.py):
the cards of every shipped reference on two suites, two episodes of every registered environment and 80 steps of
every native vector environment."""

from __future__ import annotations

import json

import pytest

from tests import house_fixture as hf


@pytest.fixture(scope="module")
def recorded() -> dict:
    return json.loads(hf.FIXTURE.read_text())


@pytest.mark.parametrize("suite", hf.CARD_SUITES)
def test_reference_cards_are_bit_identical(recorded, suite):
    got = hf.card_digests(suite)
    want = {k: v for k, v in recorded.items() if k.startswith(suite + "/")}
    assert len(want) == 15
    assert got == want


@pytest.mark.parametrize("env_id", ["pbdyn/Avoid2D-v0", "pbdyn/Avoid3D-v0", "pbdyn/Gaze2D-v0", "pbdyn/Gaze3D-v0"])
def test_gym_episodes_and_vector_steps_are_bit_identical(recorded, env_id):
    got = hf.gym_episode_digest(env_id), hf.vector_digest(env_id)
    assert got[0] == (recorded[f"gym/{env_id}"], recorded[f"gym-info/{env_id}"])
    assert got[1] == (recorded[f"vector/{env_id}"], recorded[f"vector-info/{env_id}"])
