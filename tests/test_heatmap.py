"""pbdyn metrics --plot: heat maps whose squares carry exactly the metric's per-sample values (checked in the
written PNG's pixels), 2D and 3D, and bad input."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest

import pbdyn
from pbdyn.analysis.heatmap import DPI, metric_samples
from pbdyn.config import load_scenario
from pbdyn.metrics.cached import metric_params
from pbdyn.metrics.registry import compute
from pbdyn.world.maps import get_map
from pbdyn.world.rollout import default_horizon, get_rollout
from tests.conftest import pbdyn_cmd


def test_heat_map_values_are_the_metric_samples_and_the_pixels_show_them(tmp_path):
    import imageio.v2 as iio
    from matplotlib import colormaps
    from matplotlib.colors import Normalize

    sc = load_scenario("quickstart")
    ro = get_rollout(sc, get_map(sc, 4), default_horizon(sc))
    out = tmp_path / "heat.png"
    fig = pbdyn.metric_heatmaps(sc, 4, out)
    image = iio.imread(out)[:, :, :3].astype(int)
    w, h = fig.figure.canvas.get_width_height()
    assert image.shape[:2] == (h, w) and fig.figure.dpi == DPI
    assert [name for name, _, _ in fig.panels] == ["vo_feasibility", "survivability"]   # catalog order
    checked = 0
    for name, _, ax in fig.panels:
        s = metric_samples(sc, ro, name, "analytic")
        ref = compute(ro, name, **metric_params(sc, name, "analytic"))
        assert np.array_equal(s.values, ref.per_sample) and s.value == ref.value
        assert s.points.shape == (64, 2)
        pos = ro.at(0)[0]
        cmap, norm = colormaps["viridis"], Normalize(*s.scale)
        for (x, y), v in zip(s.points, s.values):
            gap = np.abs(np.linalg.norm(pos - [x, y], axis=1) - ro.radii)
            if gap.min() < 0.6:                      # an obstacle's outline passes near the sample's centre
                continue
            px, py = ax.transData.transform((x, y))
            pixel = image[int(round(h - py)), int(round(px))]
            want = np.round(np.asarray(cmap(norm(v))[:3]) * 255).astype(int)
            assert np.abs(pixel - want).max() <= 3, (name, x, y, v, pixel, want)
            checked += 1
    assert checked >= 60


def test_3d_heat_maps_have_a_panel_per_layer_and_bad_plots_are_one_line_errors(tmp_path):
    fig = pbdyn.metric_heatmaps("spheres_3d", 1, tmp_path / "heat3.svg", metrics=["survivability", "density"])
    assert [(n, z) for n, z, _ in fig.panels] == [("survivability", 2.0), ("survivability", 8.0),
                                                   ("survivability", 14.0)]
    assert (tmp_path / "heat3.svg").read_text().lstrip().startswith("<?xml")
    for args, flag in ((["--plot", str(tmp_path / "x.jpg")], "--plot"),
                       (["--plot", str(tmp_path / "x.png"), "--metric", "density"], "--plot"),
                       (["--plot", str(tmp_path / "no" / "x.png")], "--plot")):
        res = subprocess.run(pbdyn_cmd() + ["metrics", "quickstart", *args], capture_output=True, text=True,
                             timeout=120)
        assert res.returncode == 2 and flag in res.stderr and len(res.stderr.strip().splitlines()) == 1, res.stderr
    assert not list(tmp_path.glob("x*")) and not list(tmp_path.glob(".x*"))


@pytest.mark.parametrize("dense", [False, True])
def test_pbdyn_metrics_plot_writes_the_figure(tmp_path, dense):
    out = tmp_path / "m.pdf"
    res = subprocess.run(pbdyn_cmd() + ["metrics", "quickstart", "--map", "2", "--plot", str(out)]
                         + (["--dense"] if dense else []), capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert out.read_bytes().startswith(b"%PDF") and ("_dense" in res.stderr) == dense
    assert "s [higher = easier]" in res.stdout                  # units and direction beside every value


def test_imported_worlds_show_their_static_bodies_by_their_real_shapes(tmp_path):
    """An imported world's still bodies are filled where their real shape cuts the flight plane: a pixel inside a
    shelf (2 x 12 m box centred at 12, 14) is the static grey, one 1.5 m beside its long side is not."""
    import imageio.v2 as iio

    out = tmp_path / "warehouse.png"
    fig = pbdyn.metric_heatmaps(str(pbdyn.resources.find_scenario("worlds/warehouse_2d.toml")), 0, out,
                                metrics=["survivability"])
    image = iio.imread(out)[:, :, :3].astype(int)
    w, h = fig.figure.canvas.get_width_height()
    ax = fig.panels[0][2]
    grey = np.array([0x4D, 0x4D, 0x4D])
    for (x, y), is_static in (((12.0, 14.0), True), ((12.0, 10.0), True), ((14.5, 14.0), False)):
        px, py = ax.transData.transform((x, y))
        pixel = image[int(round(h - py)), int(round(px))]
        assert (np.abs(pixel - grey).max() <= 3) == is_static, (x, y, pixel)
