"""The house-round fixture: score cards and Gymnasium episodes recorded before the code was reorganised (issue "One
room for each idea"), so that the reorganisation can be proved to keep them bit for bit. Rows and traces are the
trial-core fixture's (tests/core_fixture.py).

tests/data/house_digests.json holds, per case, the sha256 of what the code at the recording produced:

- cards: every shipped reference planner's card on pbdyn-2d-v2 and pbdyn-3d-v1, made from its shipped rows against
  the suite's references (card.json, card.md and card.html, with a fixed
  date, machine and code provenance, which name the checkout and change with any edit);
- gym: two seeded episodes of each registered environment under seeded random actions, and 80 steps of each native
  vector environment with 3 sub-environments: the observations, rewards and ends ("gym/", "vector/") and, apart,
  the infos ("gym-info/", "vector-info/": the house round gave both kinds the same info keys, so these were
  recorded again after that change).

Regenerate only for an intended behaviour change: python -m tests.house_fixture
"""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
FIXTURE = Path(__file__).resolve().parent / "data" / "house_digests.json"
CARD_SUITES = ("pbdyn-2d-v2", "pbdyn-3d-v1")


def _json_default(x):
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    return str(x)


def _digest_info(h, info: dict) -> None:
    h.update(json.dumps(info, sort_keys=True, default=_json_default).encode())


def card_digests(suite_name: str) -> dict[str, str]:
    """label/part -> sha256 of every shipped reference's card on ``suite_name`` (module doc)."""
    from pbdyn.benchmark.card import make_card
    from pbdyn.benchmark.render import card_html, card_markdown
    from pbdyn.benchmark.run import clean, load_references
    from pbdyn.benchmark.suite import load_suite

    from pbdyn.benchmark import card as card_mod

    suite = load_suite(suite_name)
    refs = load_references(suite)
    out = {}
    fixed = {"machine": card_mod.machine, "code_provenance": card_mod.code_provenance}
    card_mod.machine = lambda: {"system": "fixture", "machine": "x", "cpu": "x", "cpus": 1, "python": "3"}
    card_mod.code_provenance = lambda planner, references: {
        "core": "fixture", "planner": planner.get("fingerprint"), "references": {k: "same" for k in references},
        "statement": "fixture", "git": None}
    try:
        out.update(_cards(suite, refs, make_card, clean, card_markdown, card_html))
    finally:
        card_mod.machine, card_mod.code_provenance = fixed["machine"], fixed["code_provenance"]
    return out


def _cards(suite, refs, make_card, clean, card_markdown, card_html) -> dict[str, str]:
    suite_name, out = suite.name, {}
    for label in sorted(refs):
        meta = refs[label]["meta"]
        info = {"label": label, "trajectory": meta.get("trajectory"), "gaze": meta.get("gaze"),
                "fingerprint": meta.get("fingerprint")}
        card = clean(make_card(suite, info, refs[label]["rows"], refs, date="2026-01-01T00:00:00+00:00"))
        text = json.dumps(card, indent=1, sort_keys=True, allow_nan=False)
        out[f"{suite_name}/{label}/json"] = hashlib.sha256(text.encode()).hexdigest()
        out[f"{suite_name}/{label}/md"] = hashlib.sha256(card_markdown(card).encode()).hexdigest()
        out[f"{suite_name}/{label}/html"] = hashlib.sha256(card_html(card).encode()).hexdigest()
    return out


def gym_episode_digest(env_id: str) -> tuple[str, str]:
    """sha256 of two seeded episodes of ``env_id`` under seeded random actions: (observations, rewards and ends;
    every step's info)."""
    import gymnasium

    import pbdyn.gym  # noqa: F401  (registers the ids)

    env = gymnasium.make(env_id, disable_env_checker=True)
    h, hi = hashlib.sha256(), hashlib.sha256()
    rng = np.random.default_rng(11)
    try:
        for seed in (5, 6):
            obs, info = env.reset(seed=seed)
            h.update(np.asarray(obs).tobytes())
            _digest_info(hi, info)
            done = False
            while not done:
                obs, r, term, trunc, info = env.step(rng.uniform(-1, 1, env.action_space.shape).astype(np.float32))
                h.update(np.asarray(obs).tobytes() + np.float64(r).tobytes() + bytes([term, trunc]))
                _digest_info(hi, info)
                done = term or trunc
    finally:
        env.close()
    return h.hexdigest(), hi.hexdigest()


def vector_digest(env_id: str, steps: int = 80, num_envs: int = 3) -> tuple[str, str]:
    """sha256 of ``steps`` steps of ``env_id``'s native vector environment with ``num_envs`` sub-environments:
    (observations, rewards and ends; the infos)."""
    import gymnasium

    import pbdyn.gym  # noqa: F401

    env = gymnasium.make_vec(env_id, num_envs=num_envs, vectorization_mode="vector_entry_point")
    h, hi = hashlib.sha256(), hashlib.sha256()
    rng = np.random.default_rng(13)
    try:
        obs, info = env.reset(seed=21)
        h.update(np.asarray(obs).tobytes())
        _digest_info(hi, info)
        for _ in range(steps):
            act = rng.uniform(-1, 1, env.action_space.shape).astype(np.float32)
            obs, r, term, trunc, info = env.step(act)
            h.update(np.asarray(obs).tobytes() + np.asarray(r, dtype=np.float64).tobytes()
                     + np.asarray(term).tobytes() + np.asarray(trunc).tobytes())
            _digest_info(hi, info)
    finally:
        env.close()
    return h.hexdigest(), hi.hexdigest()


def record() -> dict[str, str]:
    """Every digest of the fixture (module doc)."""
    from pbdyn.gym_ids import ENV_IDS

    out = {}
    for s in CARD_SUITES:
        out.update(card_digests(s))
    for env_id in ENV_IDS:
        out[f"gym/{env_id}"], out[f"gym-info/{env_id}"] = gym_episode_digest(env_id)
        out[f"vector/{env_id}"], out[f"vector-info/{env_id}"] = vector_digest(env_id)
    return out


if __name__ == "__main__":
    sys.path.insert(0, sys.argv[1] if len(sys.argv) > 1 else str(ROOT))   # (a snapshot of older code)
    FIXTURE.write_text(json.dumps(record(), indent=1, sort_keys=True) + "\n")
    print(FIXTURE)
