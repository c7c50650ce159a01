"""pbdyn replay: frames of a real trial's trace (count, size, an obstacle's colour where its true position projects),
GIF / MP4 / PNG files, 3D top and side views, `pbdyn run --replay`, and bad input."""

from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest

import pbdyn
from pbdyn.analysis.replay import COLOURS, FRAME_PX, Renderer, frame_count, load_trace
from tests.conftest import pbdyn_cmd

RED = np.array([int(COLOURS["obstacle"][k:k + 2], 16) for k in (1, 3, 5)])


@pytest.fixture(scope="module")
def trace2d(tmp_path_factory):
    path = tmp_path_factory.mktemp("replay") / "trace.npz"
    res = pbdyn.run_trial("quickstart", map=4, trace=path)
    return path, res


def _pixel(renderer: Renderer, panel: int, x: float, y: float) -> tuple[int, int]:
    """(row, column) of the data point (x, y) of a panel in the last drawn frame."""
    ax = renderer.axes[panel]
    px, py = ax.transData.transform((x, y))
    height = renderer.canvas.get_width_height()[1]
    return int(round(height - py)), int(round(px))


def test_gif_frames_count_size_and_an_obstacle_where_it_truly_is(trace2d, tmp_path):
    path, res = trace2d
    out = tmp_path / "trial.gif"
    summary = pbdyn.replay(path, out, every=3)
    steps = res.steps
    assert summary.frames == frame_count(steps, 3) == len(range(0, steps, 3)) + 1
    import imageio.v2 as iio

    frames = iio.mimread(out)
    assert len(frames) == summary.frames
    assert all(f.shape[:2] == (FRAME_PX, FRAME_PX) for f in frames)
    tr = load_trace(path)
    renderer = Renderer(tr)
    k = 3 * (len(frames) // 2)                                   # a frame in the middle of the flight
    image = renderer.frame(k)
    mav = tr["p"][k]
    obs = tr["obstacle_p"][k]
    far = np.argsort(-np.linalg.norm(obs - mav, axis=1))[:3]     # obstacles far from the MAV, its plan and FOV
    for i in far.tolist():
        r = float(tr["obstacle_r"][i])
        row, col = _pixel(renderer, 0, obs[i, 0] + 0.5 * r, obs[i, 1])
        assert np.abs(image[row, col].astype(int) - RED).max() <= 2, (i, image[row, col])
        gif = frames[k // 3][row, col, :3].astype(int)
        assert np.abs(gif - RED).max() <= 12                     # the GIF's palette keeps it
        row, col = _pixel(renderer, 0, obs[i, 0] + 2.5 * r + 0.5, obs[i, 1])
        assert np.abs(image[row, col].astype(int) - RED).max() > 40   # outside the disc: not obstacle red
    moved = Renderer(tr).frame(0)
    assert not np.array_equal(moved, image)                      # the frames follow the flight


def test_png_is_the_final_state_and_mp4_is_a_video(trace2d, tmp_path):
    path, res = trace2d
    png = pbdyn.replay(path, tmp_path / "end.png")
    import imageio.v2 as iio

    img = iio.imread(png.path)
    assert png.frames == 1 and img.shape[:2] == (FRAME_PX, FRAME_PX)
    pytest.importorskip("imageio_ffmpeg")
    mp4 = pbdyn.replay(path, tmp_path / "trial.mp4", every=10, fps=5)
    reader = iio.get_reader(mp4.path, format="FFMPEG")
    try:
        assert reader.count_frames() == mp4.frames == frame_count(res.steps, 10)
        assert reader.get_meta_data()["fps"] == pytest.approx(5.0)
        assert reader.get_data(0).shape[:2] == (FRAME_PX, FRAME_PX)
    finally:
        reader.close()
    assert not list(tmp_path.glob(".*"))                         # no temporary file left behind


def test_3d_has_a_top_and_a_side_view(tmp_path):
    path = tmp_path / "trace3d.npz"
    pbdyn.run_trial("spheres_3d", map=1, trace=path)
    tr = load_trace(path)
    renderer = Renderer(tr)
    k = min(20, renderer.n_steps - 1)
    image = renderer.frame(k)
    assert image.shape[:2] == (FRAME_PX, 2 * FRAME_PX) and len(renderer.axes) == 2
    obs = tr["obstacle_p"][k]
    i = int(np.argmax(np.linalg.norm(obs - tr["p"][k], axis=1)))
    r = float(tr["obstacle_r"][i])
    hits = 0
    for panel, (a, b) in enumerate(((0, 1), (0, 2))):           # the same sphere in both views
        row, col = _pixel(renderer, panel, obs[i, a] + 0.4 * r, obs[i, b])
        hits += np.abs(image[row, col].astype(int) - RED).max() <= 2
    assert hits >= 1


def test_run_replay_and_bad_input_are_one_line_errors(trace2d, tmp_path):
    path, _ = trace2d
    out = tmp_path / "run.gif"
    res = subprocess.run(pbdyn_cmd() + ["run", "quickstart", "--map", "1", "--replay", str(out), "--json"],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout)["outcome"] and out.stat().st_size > 0
    cases = [(["replay", str(tmp_path / "missing.npz"), "--out", str(tmp_path / "x.gif")], "TRACE"),
             (["replay", str(path), "--out", str(tmp_path / "x.avi")], "--out"),
             (["replay", str(path), "--out", str(tmp_path / "no" / "x.gif")], "--out"),
             (["replay", str(path), "--out", str(tmp_path / "x.gif"), "--every", "0"], "--every"),
             (["run", "quickstart", "--replay", str(tmp_path / "x.bmp")], "--replay")]
    old = tmp_path / "old.npz"
    np.savez(old, t=np.zeros(2), p=np.zeros((2, 2)))
    cases.append((["replay", str(old), "--out", str(tmp_path / "x.gif")], "TRACE"))
    for args, flag in cases:
        res = subprocess.run(pbdyn_cmd() + args, capture_output=True, text=True, timeout=120)
        assert res.returncode == 2 and flag in res.stderr and len(res.stderr.strip().splitlines()) == 1, \
            (args, res.stderr)
    assert not (tmp_path / "x.gif").exists()
