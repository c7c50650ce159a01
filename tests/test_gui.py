"""Seeing a trial in PyBullet: the headless snapshot (TinyRenderer) frames the arena and shows the MAV's marker; the
observers change no result; the GUI's camera and pacing helpers."""

from __future__ import annotations

import json
import subprocess
import time

import numpy as np
import pytest

import pbdyn
from pbdyn.sim.gui import MAV_RGBA, SNAPSHOT_PX, GuiView, Snapshot, arena_camera, project
from tests.conftest import pbdyn_cmd


def _row(res) -> dict:
    d = res.without_wall_times()
    d.pop("planner_fingerprint", None)
    return d


def test_snapshot_frames_the_arena_and_shows_the_mav_without_changing_the_trial(tmp_path):
    import imageio.v2 as iio

    snap = Snapshot(tmp_path / "final.png")
    res = pbdyn.run_trial("quickstart", map=4, trace=tmp_path / "t.npz", observers=[snap])
    assert _row(res) == _row(pbdyn.run_trial("quickstart", map=4))         # observers change nothing
    image = iio.imread(tmp_path / "final.png")[:, :, :3]
    assert image.shape == (SNAPSHOT_PX, SNAPSHOT_PX, 3) and np.array_equal(image, snap.image)
    assert len(np.unique(image.reshape(-1, 3), axis=0)) > 50                 # not blank
    sc = pbdyn.load_scenario("quickstart")
    h = sc.world.flight_height
    corners = [[0.0, 0.0, h], [50.0, 0.0, h], [0.0, 50.0, h], [50.0, 50.0, h]]
    px = project(snap.view, snap.proj, corners, SNAPSHOT_PX, SNAPSHOT_PX)
    assert np.all((px > 0) & (px < SNAPSHOT_PX))                              # the whole arena in view
    final = np.load(tmp_path / "t.npz")["final_p"]
    row, col = project(snap.view, snap.proj, [[final[0], final[1], h + 0.1]], SNAPSHOT_PX, SNAPSHOT_PX)[0]
    pixel = image[int(round(row)), int(round(col))].astype(int)
    want = np.asarray(MAV_RGBA[:3]) * 255
    assert pixel[0] > 150 and pixel[2] < 90 and abs(pixel[1] / pixel[0] - want[1] / want[0]) < 0.2, pixel


def test_3d_snapshot_and_cli_flag(tmp_path):
    out = tmp_path / "s3.png"
    res = subprocess.run(pbdyn_cmd() + ["run", "spheres_3d", "--map", "1", "--gui-snapshot", str(out), "--json"],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout)["outcome"]
    import imageio.v2 as iio

    image = iio.imread(out)[:, :, :3]
    assert len(np.unique(image.reshape(-1, 3), axis=0)) > 50
    bad = subprocess.run(pbdyn_cmd() + ["run", "quickstart", "--gui-snapshot", str(tmp_path / "s.jpg")],
                         capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "--gui-snapshot" in bad.stderr and len(bad.stderr.strip().splitlines()) == 1


def test_arena_camera_fits_the_arena_and_the_gui_paces_to_the_wall_clock():
    cam = arena_camera((50.0, 50.0), 2.0, 2)
    assert cam.target == (25.0, 25.0, 2.0) and cam.pitch < -89.0
    wide = arena_camera((100.0, 40.0), 2.0, 2)
    assert wide.distance > 1.9 * cam.distance                                 # the larger side decides

    view = GuiView(0.05, real_time=True)
    t0 = time.perf_counter()
    for _ in range(6):
        time.sleep(0.02)                     # a step that computes for 20 ms ...
        view.pace(done=False)
    elapsed = time.perf_counter() - t0       # ... is paced to 50 ms of wall clock, not 20 + 50
    assert 0.28 <= elapsed < 0.36, elapsed
    assert 0.0 < view.slept <= elapsed - 0.11                                # the 6 x 20 ms of compute were not slept
    fast = GuiView(0.05, real_time=False)
    t0 = time.perf_counter()
    for _ in range(6):
        fast.pace(done=False)
    assert time.perf_counter() - t0 < 0.05 and fast.steps == 6


def test_the_gui_observer_runs_its_drawing_path_and_changes_nothing():
    """Without a display PyBullet's debug items are no-ops (ids -1), but GuiView's whole path runs every step (MAV
    marker, camera framing and following, FOV, plan and goal lines) and the trial's row is unchanged."""
    view = GuiView(0.1, real_time=False, follow=True)
    res = pbdyn.run_trial("quickstart", map=4, observers=[view])
    assert view.steps == res.steps > 0
    assert {"goal0", "goal1", "goal_post", "fov0", "fov1", "plan0", "plan23"} <= set(view.items)
    assert _row(res) == _row(pbdyn.run_trial("quickstart", map=4))


GUI_SCRIPT = r'''
import json, time, pbdyn
import pbdyn.sim.gui as gui
seen = {}
class Watch:
    def on_step(self, env, agent, decision, record):
        if "camera" not in seen and record.t > 0:    # GuiView framed the arena at the first step
            cam = env.world.client.getDebugVisualizerCamera()
            seen["camera"] = [list(cam[11]), cam[10], cam[9]]
    def on_end(self, env, agent):
        pass
def on_end(self, env, agent):
    seen["items"] = self.items
    seen["slept"] = self.slept
gui.GuiView.on_end = on_end
t0 = time.perf_counter()
res = pbdyn.run_trial("quickstart", map=4, start=(4.0, 4.0), goal=(20.0, 20.0), v_max=6.0, gui=True, observers=[Watch()])
t1 = time.perf_counter()
print(json.dumps({"wall": t1 - t0, "flight": res.flight_time_s, "outcome": res.outcome, **seen}))
'''


def test_the_gui_frames_the_arena_draws_its_lines_and_runs_in_real_time(tmp_path):
    """A real PyBullet GUI on a virtual display (xvfb, installed by make test where apt exists): the camera looks
    at the arena's centre from above, every debug line exists (ids >= 0), and the trial takes at least its flight
    time on the wall clock (real time) but not much more than the larger of its flight time and its compute time
    (wall clock minus the time the view slept): a software-rendered window may be slower than real time, and then the
    view must not add its waits on top."""
    import shutil
    import sys

    if shutil.which("xvfb-run") is None:
        pytest.skip("no xvfb-run on this machine (make test installs xvfb with apt)")
    res = subprocess.run(["xvfb-run", "-a", "-s", "-screen 0 1280x1024x24", sys.executable, "-c", GUI_SCRIPT],
                         capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert res.returncode == 0, res.stderr[-2000:]
    doc = json.loads(res.stdout.strip().splitlines()[-1])
    target, distance, pitch = doc["camera"]
    sc = pbdyn.load_scenario("quickstart")
    assert target == pytest.approx([25.0, 25.0, sc.world.flight_height], abs=1e-3) and pitch < -89.0
    assert distance > 20.0
    assert all(v >= 0 for v in doc["items"].values()) and len(doc["items"]) >= 29
    compute = doc["wall"] - doc["slept"]
    assert doc["flight"] <= doc["wall"] <= 1.5 * max(doc["flight"], compute) + 2.0, doc
    assert doc["slept"] < doc["flight"] - 1.0, doc          # each step's compute is inside its dt, not added to it

