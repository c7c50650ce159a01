"""pbdyn replay: frames of a real trial's trace (count, size, an obstacle's colour where its true position projects),
GIF / MP4 / PNG files, 3D top and side views, `pbdyn run --replay`, and bad input; crafted traces (shapes, values, a
zip bomb) refused with one line, a long GIF streamed in bounded memory, frame rates checked and kept, imported
worlds' still bodies drawn, names drawn as text."""

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


# ------------------------------------------------------------------------ integrity round 3: replay
GREY = np.array([int(COLOURS["static"][k:k + 2], 16) for k in (1, 3, 5)])
_PEAK_RSS = ("import json, resource, subprocess, sys\n"
             "r = subprocess.run(sys.argv[1:], capture_output=True, text=True)\n"
             "print(json.dumps([r.returncode, r.stderr, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss]))")
"""Runs a command and prints [exit status, stderr, its peak resident set size in KiB] (only this wrapper's child)."""


def _peak_rss(args: list[str]) -> tuple[int, str, int]:
    import sys

    res = subprocess.run([sys.executable, "-c", _PEAK_RSS, *pbdyn_cmd(), *args], capture_output=True, text=True,
                         timeout=900)
    code, err, kib = json.loads(res.stdout)
    return code, err, kib


def _crafted(trace_path, out, **changes) -> str:
    """A copy of a real trace with some arrays replaced (None: removed)."""
    with np.load(trace_path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    for k, v in changes.items():
        if v is None:
            arrays.pop(k, None)
        else:
            arrays[k] = v
    np.savez(out, **arrays)
    return str(out)


def _liar(trace_path, out) -> str:
    """A trace whose plan.npy header declares 10**12 floats (8 TB) and holds 16 bytes."""
    import io
    import zipfile

    _crafted(trace_path, out, plan=None)
    header = {"descr": "<f8", "fortran_order": False, "shape": (10 ** 12,)}
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, header)
    with zipfile.ZipFile(out, "a") as zf:
        zf.writestr("plan.npy", buf.getvalue() + b"\0" * 16)
    return str(out)


def test_crafted_traces_are_refused_with_one_line(trace2d, tmp_path):
    from pbdyn.errors import ConfigError

    path, _ = trace2d
    with np.load(path) as z:
        s, d = z["p"].shape
    cases = {
        "1-D p": dict(p=np.zeros(s)),
        "p of 0 columns": dict(p=np.zeros((s, 0))),
        "dt = 0": dict(dt=np.array(0.0)),
        "NaN arena": dict(arena_hi=np.array([np.nan, 50.0])),
        "arena lo >= hi": dict(arena_lo=np.array([50.0, 0.0]), arena_hi=np.array([0.0, 50.0])),
        "empty arrays": dict(t=np.zeros(0), p=np.zeros((0, d)), yaw=np.zeros(0)),
        "p rows != t": dict(p=np.zeros((s + 3, d))),
        "inf obstacle": dict(obstacle_p=np.full((s + 1, 1, d), np.inf), obstacle_r=np.ones(1)),
        "negative radius": dict(mav_radius=np.array(-1.0)),
        "text where numbers go": dict(yaw=np.array(["a"] * s)),
        "huge coordinates": dict(start=np.array([1e300, 0.0])),
    }
    for name, change in cases.items():
        bad = _crafted(path, tmp_path / f"{len(name)}.npz", **change)
        with pytest.raises(ConfigError) as info:
            load_trace(bad)
        text = str(info.value)
        assert text.startswith("TRACE:") and "\n" not in text, (name, text)
    with pytest.raises(ConfigError, match="TRACE"):
        load_trace(_liar(path, tmp_path / "liar.npz"))


def test_a_zip_bomb_trace_is_refused_before_it_is_unpacked(trace2d, tmp_path):
    import zipfile

    path, _ = trace2d
    bomb = tmp_path / "bomb.npz"
    with np.load(path) as z:
        s, d = z["p"].shape
    _crafted(path, bomb, plan=None)
    k = (1200 * 2 ** 20) // (8 * s * d)                          # plan [S, K, d]: 1.2 GiB of zeros unpacked
    header = {"descr": "<f8", "fortran_order": False, "shape": (s, k, d)}
    with zipfile.ZipFile(bomb, "a", compression=zipfile.ZIP_DEFLATED, compresslevel=1) as zf, \
            zf.open("plan.npy", "w", force_zip64=True) as fh:
        np.lib.format.write_array_header_1_0(fh, header)
        chunk, left = bytes(2 ** 24), 8 * s * k * d
        while left:
            fh.write(chunk[:min(left, len(chunk))])
            left -= min(left, len(chunk))
    assert bomb.stat().st_size < 20 * 2 ** 20
    code, err, kib = _peak_rss(["replay", str(bomb), "--out", str(tmp_path / "x.png")])
    assert code == 2 and err.startswith("pbdyn: error: TRACE") and len(err.strip().splitlines()) == 1, err
    assert kib < 400 * 1024, kib                                  # never unpacked
    assert not (tmp_path / "x.png").exists()


def test_a_long_gif_is_streamed_in_bounded_memory(trace2d, tmp_path):
    """150 steps -> 151 frames: the frames are written as they are drawn (held, at ~4 MB a frame, they alone would pass
    the 450 MB bound)."""
    path, _ = trace2d
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    n = 150
    idx = np.arange(n) % arrays["t"].shape[0]
    for key in ("p", "v", "a", "yaw", "yaw_rate", "plan_ok", "plan", "track_mean", "track_std", "track_active",
                "seen"):
        arrays[key] = arrays[key][idx]
    arrays["obstacle_p"] = arrays["obstacle_p"][np.arange(n + 1) % arrays["obstacle_p"].shape[0]]
    arrays["t"] = np.arange(n) * float(arrays["dt"])
    long = tmp_path / "long.npz"
    np.savez_compressed(long, **arrays)
    out = tmp_path / "long.gif"
    code, err, kib = _peak_rss(["replay", str(long), "--out", str(out), "--json"])
    assert code == 0 and err == "", err
    from PIL import Image

    with Image.open(out) as im:
        assert im.n_frames == n + 1 and im.size == (FRAME_PX, FRAME_PX)
    assert kib < 450 * 1024, kib
    assert sorted(p.name for p in tmp_path.iterdir()) == ["long.gif", "long.npz"]


def _gif_delays(path) -> list[int]:
    from PIL import Image, ImageSequence

    with Image.open(path) as im:
        return [int(f.info["duration"]) for f in ImageSequence.Iterator(im)]


def test_frame_rates_are_validated_and_kept(trace2d, tmp_path):
    path, res = trace2d
    for args, flag in ((["--fps", "100"], "--fps"), (["--fps", "0.01"], "--fps"), (["--every", "-2"], "--every"),
                       (["--every", "1.5"], "--every"), (["--fps", "nan"], "--fps")):
        r = subprocess.run(pbdyn_cmd() + ["replay", str(path), "--out", str(tmp_path / "x.gif"), *args],
                           capture_output=True, text=True, timeout=120)
        assert r.returncode == 2 and flag in r.stderr and len(r.stderr.strip().splitlines()) == 1, (args, r.stderr)
    assert not list(tmp_path.iterdir())
    summary = pbdyn.replay(path, tmp_path / "a.gif", fps=30, every=3)
    delays = _gif_delays(summary.path)
    assert len(delays) == summary.frames and min(delays) >= 20
    assert abs(sum(delays) - 1000.0 * summary.frames / 30) <= 10            # 30 frames a second on average
    fast = _crafted(path, tmp_path / "fast.npz", dt=np.array(0.001))       # real time would be 1000 fps
    delays = _gif_delays(pbdyn.replay(fast, tmp_path / "fast.gif", every=5).path)
    assert set(delays) == {20}                                             # the fastest a GIF plays: 50 fps


def test_imported_worlds_static_bodies_are_drawn(tmp_path):
    path = tmp_path / "warehouse.npz"
    pbdyn.run_trial("scenarios/worlds/warehouse_2d.toml", trace=path)
    tr = load_trace(path)
    renderer = Renderer(tr)
    image = renderer.frame(0)
    shelves = [(x, y) for x in (12.0, 18.0, 32.0, 38.0) for y in (14.0, 36.0)]
    grey = [np.abs(image[_pixel(renderer, 0, x, y)].astype(int) - GREY).max() <= 2 for x, y in shelves]
    assert sum(grey) >= 6, grey
    old = _crafted(path, tmp_path / "old.npz", static_outline=None)       # a trace from before: drawn without
    image = Renderer(load_trace(old)).frame(0)
    assert not any(np.abs(image[_pixel(renderer, 0, x, y)].astype(int) - GREY).max() <= 2 for x, y in shelves)

    path3 = tmp_path / "mixed.npz"
    pbdyn.run_trial("scenarios/worlds/mixed_3d.toml", trace=path3)
    renderer = Renderer(load_trace(path3))
    image = renderer.frame(0)
    for panel, (x, y) in ((0, (15.0, 15.0)), (0, (36.0, 14.0)), (0, (14.0, 36.0)),     # tower, crate, gem (top)
                          (1, (15.0, 3.0)), (1, (36.0, 8.0))):                        # tower, crate (side)
        assert np.abs(image[_pixel(renderer, panel, x, y)].astype(int) - GREY).max() <= 2, (panel, x, y)


def test_names_are_drawn_as_text_not_math(trace2d, tmp_path):
    path, _ = trace2d
    label = r"cost $\notacommand{x}^$ by planner_$a$"                       # math that matplotlib cannot parse
    crafted = _crafted(path, tmp_path / "math.npz", label=np.array(label))
    renderer = Renderer(load_trace(crafted))
    renderer.frame(3)
    assert renderer.title.get_text().startswith(label)
    r = subprocess.run(pbdyn_cmd() + ["replay", crafted, "--out", str(tmp_path / "m.png")], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0 and r.stderr == "", r.stderr
