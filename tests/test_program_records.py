"""tools/program_records.py: a thesis_program store on the program's own maps against the program's recorded trials."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pandas as pd
import pytest

from pbdyn.api import run_batch
from tools import program_records as pr

ROOT = Path(__file__).resolve().parents[1]
COLUMNS = ["Method", "Planner", "Motion Profile", "Map ID", "Agent size", "Number of agents", "Number of pillars",
           "Agent speed", "Drone speed", "Depth variance", "Initial position", "Target position", "Flight time",
           "Success", "Static Collision", "Dynamic Collision", "Freezing", "Dead Lock"]


def _record(map_id, start, goal, flags, method="NoControl", profile="CVM", size=10):
    s, d, st, dl = flags
    return ["NoControl" if method is None else method, "Jerk_Primitive", profile, map_id, size, 10, 0, 20, 60, 0,
            str(start), str(goal), 5.0, s, st, d, 0, dl]


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    """Four trials of the controlled thesis set on the program's map 0 (10 obstacles of 1 m at 2 m/s, 6 m/s MAV)."""
    doc = tomllib.loads((ROOT / "scenarios" / "thesis" / "controlled_2d.toml").read_text())
    doc["obstacles"].update(count=[10], radius=[1.0], speed=[2.0], maps_per_setup=1)
    doc["drone"]["v_max"] = [6.0]
    doc["task"]["candidates"] = [[3.0, 3.0], [45.0, 45.0]]
    doc["planners"] = [p for p in doc["planners"] if p["name"] == "NoControl+Jerk_Primitive"]
    doc["name"] = "records_test"
    path = tmp_path_factory.mktemp("records") / "s.sqlite"
    run_batch(doc, path, workers=1, metrics=False, progress=False)
    return path


def test_store_trials_are_keyed_in_the_programs_pixels(store):
    df = pr.read_store(store)
    assert len(df) == 2 and set(df["combo"]) == {"NoControl+Jerk_Primitive"}
    assert set(df["start"]) == {(40, 40), (460, 460)} and set(df["goal"]) == {(40, 40), (460, 460)}
    assert set(zip(df["map_id"], df["count"], df["radius_px"], df["speed_px"], df["mav_px"])) == {(0, 10, 10, 20, 60)}


def test_records_match_trial_by_trial_and_the_differences_are_paired(store, tmp_path):
    flown = pr.read_store(store).set_index("start")["outcome"]
    ok = flown[(40, 40)] == "success"
    rows = [_record(0, (40, 40), (460, 460), (1, 0, 0, 0) if ok else (0, 1, 0, 0)),     # ends as pbdyn's
            _record(0, (460, 460), (40, 40), (0, 0, 0, 1)),                          # a deadlock in the record
            _record(0, (460, 460), (40, 40), (1, 0, 0, 0)),                          # a repeated run: ignored
            _record(0, (40, 40), (460, 460), (1, 0, 0, 0), profile="RVO"),           # another motion profile
            _record(1, (40, 40), (460, 460), (1, 0, 0, 0))]                          # a map pbdyn did not fly
    folder = tmp_path / "records"
    folder.mkdir()
    pd.DataFrame(rows[:2], columns=COLUMNS).to_csv(folder / "a.csv", index=False)
    pd.DataFrame(rows[2:], columns=COLUMNS).to_csv(folder / "b.csv", index=False)
    (folder / "notes.csv").write_text("x,y\n1,2\n")                                   # not a result file
    rec = pr.read_records(folder)
    assert len(rec) == 3 and list(rec["outcome"][:2]) == ["success" if ok else "dynamic_collision", "deadlock"]
    (row,) = pr.compare(pr.read_store(store), rec)
    assert (row["combo"], row["mav_speed"], row["trials"], row["matched"]) == ("NoControl+Jerk_Primitive", 6.0, 2, 2)
    assert row["alike"] == (0.5 if flown[(460, 460)] != "deadlock" else 1.0)
    assert row["deadlock"]["record"] == 0.5
    assert row["deadlock"]["diff"] == pytest.approx(row["deadlock"]["pbdyn"] - 0.5)
    assert "| NoControl+Jerk_Primitive | 6 | 2 (2) |" in pr.format_table([row])


def test_bad_inputs_name_the_argument(store, tmp_path, capsys):
    assert pr.main([str(tmp_path), str(store)]) == 2
    assert "RECORDS_DIR" in capsys.readouterr().err
    doc = {"name": "plain", "world": {"time_limit": 5.0}, "obstacles": {"count": 2},
           "task": {"candidates": [[4.0, 4.0], [46.0, 46.0]]},
           "planners": [{"trajectory": "local_primitives", "gaze": "fullrange"}]}
    plain = tmp_path / "plain.sqlite"
    run_batch(doc, plain, workers=1, metrics=False, progress=False)
    (tmp_path / "r").mkdir()
    pd.DataFrame([_record(0, (40, 40), (460, 460), (1, 0, 0, 0))], columns=COLUMNS).to_csv(tmp_path / "r" / "a.csv")
    assert pr.main([str(tmp_path / "r"), str(plain)]) == 2
    assert "STORE" in capsys.readouterr().err
