"""The pbdyn command: --json output, exit status 2 with one-line errors, rollout files, determinism across processes."""

from __future__ import annotations

import json
import os
import subprocess

import numpy as np
import pytest

from tests.conftest import ROOT, SCENARIOS, pbdyn_cmd

FAST = """
name = "fast"
[world]
time_limit = 25.0
[obstacles]
count = [12, 30]
radius = 1.0
speed = [3.0]
maps_per_setup = 2
root_seed = 5
[drone]
v_max = [6.0]
[[planners]]
trajectory = "local_primitives"
gaze = "lookahead"
[[planners]]
trajectory = "straight_line"
gaze = "lookahead"
"""


def _run(args, env=None, cwd=ROOT):
    full_env = dict(os.environ)
    full_env.update(env or {})
    return subprocess.run(pbdyn_cmd() + [str(a) for a in args], capture_output=True, text=True, env=full_env,
                          cwd=cwd, timeout=300)


def test_run_json_is_one_clean_document(write_scenario):
    path = write_scenario(FAST)
    proc = _run(["run", path, "--json"])
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout)  # nothing but the JSON document on stdout
    for key in ("gaze", "planner", "motion_profile", "map_index", "map_seed", "obstacle_count", "obstacle_radius",
                "obstacle_speed", "mav_speed", "start", "goal", "flight_time_s", "grid_discovered",
                "obstacles_tracked", "tracked_time_s", "outcome", "final_state", "min_clearance_m", "config_hash",
                "wall_time_s"):
        assert key in doc
    assert doc["start"] == [4.0, 4.0] and doc["goal"] == [46.0, 46.0]
    assert doc["planner"] == "local_primitives" and doc["mav_speed"] == 6.0
    assert all("wall" in k for k in doc if "time" in k and k not in ("flight_time_s", "tracked_time_s"))


BAD_TOML = [
    ("[world]\nsize = [50, 50]\ncolour = 3\n", "world.colour"),
    ("[obstacles]\nradius = -1.0\n", "obstacles.radius"),
    ("[obstacles]\ncount = 'ten'\n", "obstacles.count"),
    ("[obstacles]\ncount = 5000\nradius = 1.5\n", "obstacles.count"),
    ("[task]\ncandidates = [[4, 4], [80, 4]]\n", "task.candidates[1]"),
    ("[[planners]]\ntrajectory = 'warp_drive'\ngaze = 'lookahead'\n", "warp_drive"),
    ("[[planners]]\ntrajectory = 'local_primitives'\ngaze = 'nosuch.module:Gaze'\n", "nosuch.module:Gaze"),
    ("[world\n", "malformed TOML"),
]


@pytest.mark.parametrize("text, needle", BAD_TOML)
def test_bad_scenarios_exit_2_with_one_line(write_scenario, text, needle):
    path = write_scenario(text)
    proc = _run(["run", path, "--json"])
    assert proc.returncode == 2
    assert proc.stdout == ""
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0], proc.stderr
    assert "Traceback" not in proc.stderr


@pytest.mark.parametrize("args, needle", [
    (["--start", "80,4"], "--start"),
    (["--goal", "4"], "--goal"),
    (["--map", "99"], "--map"),
    (["--vmax", "-2"], "--vmax"),
    (["--planner", "nope"], "nope"),
    (["--gaze", "nope"], "nope"),
])
def test_bad_flags_exit_2(write_scenario, args, needle):
    path = write_scenario(FAST)
    proc = _run(["run", path, "--json", *args])
    assert proc.returncode == 2 and proc.stdout == ""
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0], proc.stderr


def test_missing_file_exit_2(tmp_path):
    proc = _run(["run", tmp_path / "missing.toml"])
    assert proc.returncode == 2 and "file not found" in proc.stderr and "Traceback" not in proc.stderr


def test_version_prints_the_package_version_and_exits_0(capsys):
    import pbdyn
    from pbdyn.cli import main

    proc = _run(["--version"])
    assert (proc.returncode, proc.stdout, proc.stderr) == (0, f"pbdyn {pbdyn.__version__}\n", "")
    with pytest.raises(SystemExit) as done:
        main(["--version"])
    assert done.value.code == 0 and capsys.readouterr().out == f"pbdyn {pbdyn.__version__}\n"


def test_rollout_command_writes_npz(tmp_path):
    out = tmp_path / "map3.npz"
    proc = _run(["rollout", SCENARIOS / "controlled_2d.toml", "--map", "3", "--out", out, "--json"])
    assert proc.returncode == 0, proc.stderr
    info = json.loads(proc.stdout)
    assert info["map_index"] == 3 and info["obstacles"] == 10
    with np.load(out) as z:
        assert z["positions"].shape == (902, 10, 2)   # 80 s + the start rule's 10 s wait + 1 step
    bad = _run(["rollout", SCENARIOS / "controlled_2d.toml", "--map", "540", "--out", tmp_path / "x.npz"])
    assert bad.returncode == 2 and not (tmp_path / "x.npz").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map3.npz"]


def _results(path, cache, hashseed):
    rows = []
    for m in range(3):
        for planner in ("lookahead+local_primitives", "lookahead+straight_line"):
            proc = _run(["run", path, "--json", "--map", m, "--planner", planner],
                        env={"PYTHONHASHSEED": hashseed, "PBDYN_CACHE": str(cache)})
            assert proc.returncode == 0, proc.stderr
            doc = json.loads(proc.stdout)
            rows.append({k: v for k, v in doc.items() if "wall" not in k})
    return rows


def test_determinism_across_processes_and_hash_seeds(write_scenario, tmp_path):
    path = write_scenario(FAST)
    a = _results(path, tmp_path / "cache_a", "1")
    b = _results(path, tmp_path / "cache_b", "12345")
    assert a == b
    assert len({r["outcome"] for r in a}) >= 2
    assert (tmp_path / "cache_a" / "rollouts").is_dir()


RVO_3D = """
[world]
dims = 3
time_limit = 15.0
[obstacles]
count = 20
speed = 3.0
motion = "rvo"
[drone]
v_max = 4.0
"""


@pytest.mark.parametrize("text", [RVO_3D, RVO_3D.replace("dims = 3", "dims = 2"),
                                  RVO_3D.replace('motion = "rvo"', 'motion = "cvm"')])
def test_run_and_rollout_work_in_3d_and_with_rvo_deterministically(write_scenario, tmp_path, text):
    path = write_scenario(text)
    dims = 3 if "dims = 3" in text else 2
    out = tmp_path / "r.npz"
    proc = _run(["rollout", path, "--out", out])
    assert proc.returncode == 0, proc.stderr
    with np.load(out) as z:
        assert z["positions"].shape == (442, 20, dims)  # the default metrics need 44 s
    docs = []
    for seed in ("0", "99"):
        proc = _run(["run", path, "--json", "--trace", tmp_path / f"t{seed}.npz"],
                    env={"PYTHONHASHSEED": seed, "PBDYN_CACHE": str(tmp_path / f"c{seed}")})
        assert proc.returncode == 0, proc.stderr
        docs.append({k: v for k, v in json.loads(proc.stdout).items() if "wall" not in k})
    assert docs[0] == docs[1] and len(docs[0]["start"]) == dims
    with np.load(tmp_path / "t0.npz") as a, np.load(tmp_path / "t99.npz") as b:
        assert a["p"].shape[1] == dims and np.array_equal(a["p"], b["p"])


def test_metrics_command_json_cache_and_errors(tmp_path):
    env = {"PBDYN_CACHE": str(tmp_path / "cache")}
    args = ["metrics", SCENARIOS / "quickstart.toml", "--map", "1", "--json", "--metric", "density",
            "--metric", "survivability", "--dense"]
    first = _run(args, env=env)
    assert first.returncode == 0, first.stderr
    doc = json.loads(first.stdout)
    surv = doc["metrics"]["survivability_dense"]
    assert set(doc["metrics"]) == {"density", "survivability_dense"} and surv["n_samples"] == 256
    assert 0.0 < surv["value"] <= 12.0 and surv["stderr"] > 0 and len(surv["extra"]["jitter"]["values"]) == 8
    assert not surv["cached"]
    again = json.loads(_run(args, env=env).stdout)
    assert again["metrics"]["survivability_dense"]["cached"]
    assert again["metrics"]["survivability_dense"]["value"] == surv["value"]
    bullet = _run(args + ["--backend", "bullet"], env=env)
    assert json.loads(bullet.stdout)["metrics"]["survivability_dense"]["value"] == surv["value"]
    for bad, needle in ((["--metric", "nope"], "--metric"), (["--backend", "gpu"], "--backend")):
        proc = _run(["metrics", SCENARIOS / "quickstart.toml", *bad], env=env)
        assert proc.returncode == 2 and needle in proc.stderr and proc.stdout == ""
