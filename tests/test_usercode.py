"""User code at pbdyn's boundary (pbdyn.usercode, pbdyn/world/imported/bodies.py): motion functions that return garbage,
raise or exit, hang or print; planner plug-ins that print. Every case is a one-line ConfigError naming the field
(CLI exit 2) or a clean result, and pbdyn's stdout only ever carries its own output."""

from __future__ import annotations

import io
import json
import re
import signal
import subprocess
import sys
import threading
import time

import pytest

from tests.conftest import ROOT, pbdyn_cmd
from pbdyn import cli
from pbdyn import usercode
from pbdyn.config import parse_scenario
from pbdyn.errors import ConfigError, one_line, shorten
from pbdyn.world.imported import bodies as imported
from pbdyn.world.maps import enumerate_maps
from pbdyn.world.rollout import build_rollout

M = "tests.usercode_motions"


def world_doc(motion: str, time_limit: float = 3.0, **body) -> dict:
    return {"world": {"time_limit": time_limit},
            "bodies": [{"urdf": "box.urdf", "motion": motion, **body}],
            "planners": [{"trajectory": "straight_line", "gaze": "fullrange"}]}


def world_file(tmp_path, motion: str, time_limit: float = 3.0, name: str = "world.toml", dt: float = 0.1):
    path = tmp_path / name
    path.write_text(f'[world]\ntime_limit = {time_limit}\ndt = {dt}\n[[bodies]]\nurdf = "box.urdf"\nmotion = "{motion}"\n'
                    '[[planners]]\ntrajectory = "straight_line"\ngaze = "fullrange"\n')
    return path


def rollout_error(motion: str) -> str:
    sc = parse_scenario(world_doc(motion))
    with pytest.raises(ConfigError) as info:
        build_rollout(sc, enumerate_maps(sc)[0])
    return str(info.value)


def cli_in_process(argv) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    old = sys.stdout, sys.stderr
    sys.stdout, sys.stderr = out, err
    try:
        code = cli.main([str(a) for a in argv])
    except SystemExit as exc:
        code = exc.code
    finally:
        sys.stdout, sys.stderr = old
    return code, out.getvalue(), err.getvalue()


@pytest.mark.parametrize("fn, needle", [
    ("returns_string", r"at t = 0 s .*position must be 3 real numbers; it returned 'twelve'"),
    ("returns_string_tuple", "position must be 3 real numbers"),
    ("returns_complex", r"position must be 3 real numbers; it returned \[\(25\+1j\)"),
    ("returns_none", "it returned None"),
    ("returns_dict", "it returned {'x': 1.0}"),
    ("returns_bool", "position must be 3 real numbers"),
    ("returns_short", r"position must be 3 numbers, not shape \(2,\)"),
    ("returns_nan", "at t = 0.6 s .*position must be 3 finite numbers; it returned \\[25.0, nan, 2.0\\]"),
    ("returns_inf", "position must be 3 finite numbers"),
    ("returns_huge_int", "position must be 3 finite numbers"),
    ("returns_far", r"coordinates must be within \+-1e\+06 m; it returned \[1e\+300, 25.0, 2.0\]"),
    ("returns_bad_float", "position must be 3 real numbers"),
    ("returns_multiline_array", r"not shape \(20, 10\)"),
    ("returns_zero_quat", "quaternion must not be zero"),
    ("returns_nan_quat", "quaternion must be 4 finite numbers"),
    ("returns_short_quat", r"quaternion must be 4 numbers, not shape \(3,\)"),
    ("raises_system_exit", r"raised at t = 0 s \(SystemExit: 3\)"),
    ("raises_system_exit_text", r"\(SystemExit: bye now\)"),
    ("raises_generator_exit", r"\(GeneratorExit\)"),
    ("raises_custom_base", r"\(CustomBase: not an Exception\)"),
    ("raises_value_error", r"\(ValueError: line one line two\)"),
    ("raises_unprintable", r"\(_Unprintable: <unprintable>\)"),
])
def test_bad_motion_functions_are_config_errors_naming_the_field_and_time(fn, needle):
    msg = rollout_error(f"{M}:{fn}")
    assert msg.startswith("bodies[0].motion: ") and "\n" not in msg and len(msg) < 600, msg
    assert re.search(needle, msg), msg


def test_module_that_exits_on_import_is_a_config_error():
    msg = rollout_error("tests.usercode_exit_module:f")
    assert msg.startswith("bodies[0].motion: cannot import module 'tests.usercode_exit_module' (SystemExit: 4)")


def test_keyboard_interrupt_is_not_swallowed():
    sc = parse_scenario(world_doc(f"{M}:interrupts"))
    with pytest.raises(KeyboardInterrupt):
        build_rollout(sc, enumerate_maps(sc)[0])
    assert sys.stdout is not sys.stderr      # the redirection ended with the interrupt


def test_huge_quaternions_are_normalised_without_overflow():
    p, q, problem = imported._pose(([1.0, 2.0, 3.0], [0.0, 0.0, 1e300, 1e300]))
    assert problem == "" and abs(q[2] - 2 ** -0.5) < 1e-12 and abs(q[3] - 2 ** -0.5) < 1e-12
    p, q, problem = imported._pose(__import__("numpy").array([1, 2, 3]))
    assert problem == "" and list(p) == [1.0, 2.0, 3.0] and list(q) == [0.0, 0.0, 0.0, 1.0]


def test_bad_motion_functions_exit_2_with_one_line_through_the_cli(tmp_path):
    for fn in ("raises_system_exit", "raises_custom_base", "returns_complex"):
        path = world_file(tmp_path, f"{M}:{fn}", name=f"{fn}.toml")
        proc = subprocess.run(pbdyn_cmd() + ["metrics", str(path), "--metric", "density", "--json"],
                              capture_output=True, text=True, timeout=120, cwd=ROOT)
        lines = proc.stderr.splitlines()
        assert proc.returncode == 2 and proc.stdout == "", (fn, proc.returncode, proc.stderr)
        assert len(lines) == 1 and lines[0].startswith("pbdyn: error: bodies[0].motion:"), proc.stderr


def test_a_hanging_motion_function_stops_after_the_budget(tmp_path):
    path = world_file(tmp_path, f"{M}:sleeps")
    out = tmp_path / "ro.npz"
    t0 = time.monotonic()
    proc = subprocess.run(pbdyn_cmd() + ["rollout", str(path), "--out", str(out)], capture_output=True, text=True,
                          timeout=120, cwd=ROOT)
    elapsed = time.monotonic() - t0
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.splitlines() == [
        f"pbdyn: error: bodies[0].motion: the motion function did not return within "
        f"{usercode.USER_CODE_TIMEOUT_S:g} s (its calls over the whole rollout; stopped at t = 0 s) "
        f"(got '{M}:sleeps')"]
    assert usercode.USER_CODE_TIMEOUT_S <= elapsed < usercode.USER_CODE_TIMEOUT_S + 20
    assert not out.exists()


def test_the_budget_covers_all_calls_of_a_body_in_process(monkeypatch):
    monkeypatch.setattr(imported, "USER_CODE_TIMEOUT_S", 0.3)
    handler, timer = signal.getsignal(signal.SIGALRM), signal.getitimer(signal.ITIMER_REAL)
    for fn in ("busy", "slow"):           # one call that never returns; many calls that add up (0.05 s each)
        t0 = time.monotonic()
        msg = rollout_error(f"{M}:{fn}")
        assert "did not return within 0.3 s" in msg and time.monotonic() - t0 < 5, msg
    assert signal.getsignal(signal.SIGALRM) == handler          # the budget's timer and handler are gone
    if timer == (0.0, 0.0):
        assert signal.getitimer(signal.ITIMER_REAL) == (0.0, 0.0)


def test_the_budget_outside_the_main_thread_checks_after_each_call(monkeypatch):
    monkeypatch.setattr(imported, "USER_CODE_TIMEOUT_S", 0.3)
    box = {}

    def target():
        try:
            box["msg"] = rollout_error(f"{M}:slow")
        except BaseException as exc:  # pragma: no cover - reported below
            box["msg"] = repr(exc)

    th = threading.Thread(target=target)
    th.start()
    th.join(30)
    assert "did not return within 0.3 s" in box.get("msg", ""), box


def test_time_budget_keeps_an_outer_timer_working():
    fired = []
    old = signal.signal(signal.SIGALRM, lambda s, f: fired.append(time.monotonic()))
    try:
        signal.setitimer(signal.ITIMER_REAL, 0.2)
        t0 = time.monotonic()
        with usercode.time_budget(5.0) as budget:
            while not fired and time.monotonic() - t0 < 3:   # the outer timer fires inside the budget's block
                time.sleep(0.01)
            budget.check()
        assert fired and fired[0] - t0 < 1.0
        signal.setitimer(signal.ITIMER_REAL, 0.3)
        with usercode.time_budget(5.0):                       # ... and after it, when it is due later
            pass
        time.sleep(0.6)
        assert len(fired) == 2
        with pytest.raises(usercode.UserCodeTimeout), usercode.time_budget(0.1):
            time.sleep(5)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        signal.signal(signal.SIGALRM, old)


def test_user_stdout_is_reentrant_and_restores():
    real = sys.stdout
    with usercode.user_stdout():
        assert sys.stdout is sys.stderr
        with usercode.user_stdout():
            sys.stdout = io.StringIO()     # user code replacing sys.stdout does not outlive the block
        assert sys.stdout is not real
    assert sys.stdout is real


def test_printing_motion_function_and_planner_keep_run_json_clean(tmp_path):
    path = world_file(tmp_path, f"{M}:prints")
    proc = subprocess.run(pbdyn_cmd() + ["run", str(path), "--json", "--planner", f"{M}:PrintingPlanner",
                                         "--gaze", f"{M}:PrintingGaze"],
                          capture_output=True, text=True, timeout=180, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.count("\n") == 1 and json.loads(proc.stdout)["planner"] == f"{M}:PrintingPlanner"
    for chatter in ("hello from the motion function", "PrintingPlanner.__init__ says hello",
                    "PrintingPlanner.__init__ fd 1", "replan_check?", "planning at t =", "gaze!"):
        assert chatter in proc.stderr


def test_printing_module_and_c_level_writes_keep_metrics_json_clean(tmp_path):
    for motion in ("tests.usercode_noisy_module:circle", f"{M}:prints_c_level"):
        path = world_file(tmp_path, motion, name=motion.replace(":", "_") + ".toml")
        proc = subprocess.run(pbdyn_cmd() + ["metrics", str(path), "--metric", "density", "--json"],
                              capture_output=True, text=True, timeout=120, cwd=ROOT)
        assert proc.returncode == 0, proc.stderr[-2000:]
        assert proc.stdout.count("\n") == 1 and "density" in json.loads(proc.stdout)["metrics"]
        assert "fd 1" in proc.stderr


def test_in_process_cli_keeps_stdout_clean_with_a_printing_motion_function(tmp_path):
    path = world_file(tmp_path, f"{M}:prints", time_limit=1.0, dt=0.05)   # a rollout no other test cached
    code, out, err = cli_in_process(["metrics", path, "--metric", "density", "--json"])
    assert code == 0 and json.loads(out) and "hello from the motion function" in err


def test_a_planner_that_exits_ends_the_run_with_one_line(tmp_path):
    path = tmp_path / "short.toml"
    path.write_text((ROOT / "scenarios" / "quickstart.toml").read_text().replace("time_limit = 40.0",
                                                                                "time_limit = 2.0"))
    code, out, err = cli_in_process(["run", path, "--json", "--planner", f"{M}:ExitingPlanner"])
    import inspect

    from tests.usercode_motions import ExitingPlanner

    where = f"{inspect.getsourcefile(ExitingPlanner)}:{inspect.getsourcelines(ExitingPlanner.plan)[1] + 1}"
    assert code == 2 and out == "" and err.splitlines() == [
        f"pbdyn: error: --planner: the planner pair {M}:ExitingPlanner + lookahead raised SystemExit: 7 at t = 0 s "
        f"(at {where})"]


def test_one_line_and_shorten():
    assert shorten("a\nb\r\n c\x0bd\u2028e") == "a b c d e"
    assert shorten("x\x00y\x1b[31m") == "x\\x00y\\x1b[31m"
    assert len(shorten("z" * 10_000)) == 300 and shorten("z" * 10_000).endswith("...")

    class Bad(BaseException):
        def __str__(self):
            raise SystemExit(1)
    assert one_line(Bad()) == "Bad: <unprintable>"
    assert one_line(ValueError("")) == "ValueError"
