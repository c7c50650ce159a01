"""tools/use_case_5_2_2.py (thesis 5-2-2) at a tiny scale: its outputs, the signs of the eq. 5-1 fit, the generated
maps of the two fig. 5-12 requests, and the eq. 5-2 solution."""

from __future__ import annotations

import json

import pytest

from tools import use_case_5_2_2 as uc


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("use_case")
    assert uc.main(["--out", str(out), "--maps", "1", "--setups", "corners", "--count", "2", "--ilp-maps", "2",
                    "--workers", "1"]) == 0
    return out, json.loads((out / "summary.json").read_text())


def test_outputs_exist(run):
    out, _ = run
    for name in ("fig_5_11.png", "fig_5_12a.png", "fig_5_12b.png", "fig_5_12a.toml", "fig_5_12b.toml",
                 "summary.md", "summary.json"):
        assert (out / name).stat().st_size > 0, name
    assert "Table 5-4" in (out / "summary.md").read_text()


def test_eq_5_1_has_the_thesis_signs_on_the_difficulty_scale(run):
    _, res = run
    assert res["maps"] == 8
    diff, raw = res["fit"]["difficulty"], res["fit"]["raw"]
    assert diff["coef"][0] < 0 and all(c > 0 for c in diff["coef"][1:])        # table 5-4: -6.014, +, +, +
    assert all(c < 0 for c in raw["coef"][1:])                                  # fewer seconds = harder
    assert diff["r2"] == pytest.approx(raw["r2"]) and diff["r2"] > 0.8
    assert all(s > 0 for s in diff["se"])


def test_generated_maps_meet_the_requests(run):
    _, res = run
    assert [(q["panel"], q["difficulty_target"]) for q in res["requests"]] == [("a", 5.0), ("b", 7.0)]
    for q in res["requests"]:
        g = q["generated"]
        assert g["maps"] == 2 and g["within_tolerance_again"] == 1.0
        assert all(s[0] == q["fixed"]["count"] for s in g["setups"])
        if "radius" in q["fixed"]:
            assert all(s[1] == q["fixed"]["radius"] for s in g["setups"])
        for ilp in q["ilp"]:
            assert ilp["count"] == q["fixed"]["count"] and ilp["maps"] == 2


def test_eq_5_2_solves_the_free_value_within_the_box():
    best = uc.ilp_setup(uc.THESIS_COEF, 7.0, {"count": 25, "radius": 1.2})
    assert (best["count"], best["radius"]) == (25, 1.2)
    assert best["speed"] == pytest.approx((7.0 + 6.014 - 0.226 * 25 - 2.646 * 1.2) / 1.104)
    assert best["predicted"] == pytest.approx(7.0)
    low = uc.ilp_setup(uc.THESIS_COEF, -100.0, {})                    # unreachable: the easiest corner
    assert (low["count"], low["radius"], low["speed"]) == (10, 0.5, 2.0)
    mid = uc.ilp_setup(uc.THESIS_COEF, 5.0, {"count": 10})
    assert mid["predicted"] == pytest.approx(5.0) and 0.5 <= mid["radius"] <= 1.5 and 2.0 <= mid["speed"] <= 6.0
