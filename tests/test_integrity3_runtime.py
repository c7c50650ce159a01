"""Integrity round 3, at run time, each in real subprocesses: a corrupt native library is never loaded; a read-only
installation with no writable HOME runs quietly; output and cache files follow the umask; batch workers end without
PyBullet's shutdown traceback, and run, metrics and evaluate leave stderr empty; --gui without a display is one line
and exit 2.

Tests that corrupt or lock a package work on a copy of the checkout (pbdyn/, urdf/, scenarios/, setup.cfg), run
with ``python -m pbdyn`` from the copy's folder, never on the repository's own files."""

from __future__ import annotations

import json
import os
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.helpers import copy_checkout

ROOT = Path(__file__).resolve().parents[1]
NATIVE = Path("pbdyn") / "planning" / "primitives" / "native" / "_ruckig_batch.so"
STATUS = "from pbdyn.planning.primitives import native; print(native.status())"




def _env(**extra) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("PBDYN_NATIVE", "PBDYN_NATIVE_REPORTED")}
    env["PYTHONHASHSEED"] = "0"
    env.update(extra)
    return env


def _python(cwd: Path, *args, env: dict | None = None, timeout: float = 600, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *args], cwd=cwd, env=env if env is not None else _env(),
                          capture_output=True, text=True, timeout=timeout, **kw)


def _row(stdout: str) -> dict:
    return {k: v for k, v in json.loads(stdout).items() if "wall" not in k}


# ------------------------------------------------------------------------------------- (A) the native library
@pytest.fixture(scope="module")
def checkout(tmp_path_factory):
    """A copy of the checkout holding a good native library (the repository's, else one built into the copy):
    (folder, the library's bytes, {file name: bytes} of the files beside it that the build wrote)."""
    dest = copy_checkout(tmp_path_factory.mktemp("checkout"))
    assert _python(dest, "-c", "import pbdyn; print(pbdyn.__file__)").stdout.strip() == str(dest / "pbdyn" /
                                                                                          "__init__.py")
    lib = dest / NATIVE
    if not (lib.is_file() and lib.with_name(lib.name + ".sha256").is_file()):
        from pbdyn.planning.primitives.native.build import BuildError, build

        try:
            build(output=lib)
        except BuildError as exc:
            pytest.skip(f"native ruckig batch not available: {exc}")
    beside = {p.name: p.read_bytes() for p in lib.parent.glob(lib.name + ".*")}
    return dest, lib.read_bytes(), beside


def _install(checkout, data: bytes | None = None, *, beside: bool = True) -> Path:
    """Put ``data`` (default: the good library) at the copy's library path, with (``beside``) or without the
    files the build wrote beside it."""
    dest, good, extra = checkout
    lib = dest / NATIVE
    lib.write_bytes(good if data is None else data)
    for name, content in extra.items():
        (lib.parent / name).unlink(missing_ok=True)
        if beside:
            (lib.parent / name).write_bytes(content)
    return lib


def _corrupt(good: bytes, how: str) -> bytes:
    if how == "truncated":
        return good[: len(good) // 2]
    if how == "garbage":
        return np.random.default_rng(5).integers(0, 256, len(good), dtype=np.uint8).tobytes()
    flipped = bytearray(good)            # the ELF header kept, code and data flipped
    for i in range(0x3000, len(flipped) - 0x20000, 97):
        flipped[i] ^= 0xFF
    return bytes(flipped)


@pytest.fixture(scope="module")
def python_row(checkout):
    """`pbdyn run quickstart --json` in the copy with the library switched off (PBDYN_NATIVE=0)."""
    _install(checkout)
    done = _python(checkout[0], "-m", "pbdyn", "run", "quickstart", "--json", env=_env(PBDYN_NATIVE="0"))
    assert done.returncode == 0 and not done.stderr, done.stderr
    return _row(done.stdout)


def test_the_intact_library_is_used_quietly(checkout):
    _install(checkout)
    done = _python(checkout[0], "-c", STATUS)
    assert (done.returncode, done.stdout, done.stderr) == (0, "native ruckig batch: in use\n", "")


@pytest.mark.parametrize("how", ["truncated", "flipped", "garbage"])
def test_a_corrupt_library_is_never_loaded(checkout, python_row, how):
    """A truncated, bit-flipped or garbage library: `pbdyn run` flies as with PBDYN_NATIVE=0 and says so in one
    line; native.status() reports it (no signal: these used to end with SIGBUS / SIGSEGV)."""
    _install(checkout, _corrupt(checkout[1], how))
    done = _python(checkout[0], "-m", "pbdyn", "run", "quickstart", "--json")
    assert done.returncode == 0, (done.returncode, done.stderr)
    assert _row(done.stdout) == python_row
    lines = done.stderr.splitlines()
    assert len(lines) == 1 and "_ruckig_batch.so" in lines[0] and "ruckig Python package" in lines[0], lines
    status = _python(checkout[0], "-c", STATUS)
    assert status.returncode == 0, (status.returncode, status.stderr)
    assert status.stdout == "native ruckig batch: present, not used\n"
    assert len(status.stderr.splitlines()) == 1, status.stderr


def test_a_library_without_its_checksum_is_not_loaded(checkout):
    """A library the build did not certify (no checksum beside it, e.g. an older build): not used, one line."""
    _install(checkout, beside=False)
    done = _python(checkout[0], "-c", STATUS)
    assert done.returncode == 0 and done.stdout == "native ruckig batch: present, not used\n"
    lines = done.stderr.splitlines()
    assert len(lines) == 1 and "_ruckig_batch.so" in lines[0] and "rebuild" in lines[0], lines


def test_a_batch_with_a_corrupt_library_says_so_once(checkout, tmp_path):
    """`pbdyn batch` with two worker processes and a truncated library: exit 0, one line about the library."""
    _install(checkout, _corrupt(checkout[1], "truncated"))
    done = _python(checkout[0], "-m", "pbdyn", "batch", "quickstart", "--out", str(tmp_path / "r.sqlite"),
                   "--limit", "4", "--workers", "2")
    assert done.returncode == 0, (done.returncode, done.stderr)
    about = [ln for ln in done.stderr.splitlines() if "_ruckig_batch.so" in ln]
    assert len(about) == 1, done.stderr
    assert not [ln for ln in done.stderr.splitlines() if ln not in about and not ln.startswith("pbdyn batch: ")]


def test_the_checksum_check(tmp_path):
    """No record: "rebuild"; a record of these bytes: loadable; one byte less: refused."""
    from pbdyn.planning.primitives import native

    lib = tmp_path / "lib.so"
    lib.write_bytes(b"\x7fELF" + bytes(range(256)) * 8)
    assert "rebuild" in native.integrity_problem(lib)
    native.write_checksum(lib)
    assert native.integrity_problem(lib) is None
    lib.write_bytes(lib.read_bytes()[:-1])
    assert "checksum" in native.integrity_problem(lib)


def test_the_build_certifies_only_a_library_that_runs(checkout, tmp_path):
    """The build's probe runs a library in a child process: a good one passes, a truncated one (SIGBUS there) and
    garbage are refused with a BuildError, and the caller survives."""
    from pbdyn.planning.primitives.native.build import BuildError, probe

    good = tmp_path / "good.so"
    good.write_bytes(checkout[1])
    probe(good)
    for how in ("truncated", "garbage"):
        bad = tmp_path / f"{how}.so"
        bad.write_bytes(_corrupt(checkout[1], how))
        with pytest.raises(BuildError, match="failed its probe run"):
            probe(bad)


# ---------------------------------------------------------------------------- (B) read-only, no writable HOME
def test_a_read_only_installation_with_no_writable_home_runs_quietly(tmp_path):
    """No folder numba can cache in beside the modules (each __pycache__ is a file: this holds for root too, who
    ignores permission bits), HOME and XDG_CACHE_HOME under a file, the package read-only: `pbdyn run` works,
    stderr stays empty, and numba caches in a private folder of the temp folder instead."""
    root = copy_checkout(tmp_path / "ro", caches=False)
    folders = [root / "pbdyn", *[p for p in (root / "pbdyn").rglob("*") if p.is_dir()]]
    for folder in folders:
        (folder / "__pycache__").write_bytes(b"")
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    env = _env(HOME=str(blocker / "home"), XDG_CACHE_HOME=str(blocker / "cache"), TMPDIR=str(tmp),
               PBDYN_CACHE=str(blocker / "pbdyn-cache"))
    env.pop("NUMBA_CACHE_DIR", None)
    for p in [*folders, *(root / "pbdyn").rglob("*.*")]:
        p.chmod(p.stat().st_mode & ~0o222)
    try:
        done = _python(root, "-m", "pbdyn", "run", "quickstart", "--json", env=env)
    finally:
        for p in folders:
            p.chmod(p.stat().st_mode | stat.S_IWUSR)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stderr == "" and json.loads(done.stdout)["outcome"]
    assert list(tmp.rglob("*.nbi")), "numba cached nothing in the temp folder"


@pytest.mark.parametrize("fallback", ["usable", "a file", "writable by others"])
def test_pbdyn_njit_caches_in_a_private_temp_folder_or_not_at_all(tmp_path, fallback):
    """A module whose folder numba cannot cache in, HOME under a file: pbdyn.jit.njit(cache=True) compiles and
    runs; it caches in <temp>/pbdyn-numba-<uid> only if that is a folder no one else can write to."""
    mod = tmp_path / "mod"
    mod.mkdir()
    (mod / "__pycache__").write_bytes(b"")
    (mod / "jitted.py").write_text("from pbdyn.jit import njit\n\n\n@njit(cache=True, nogil=True)\n"
                                   "def twice(x):\n    return 2 * x\n")
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    private = tmp / f"pbdyn-numba-{os.getuid()}"
    if fallback == "a file":
        private.write_text("")
    elif fallback == "writable by others":
        private.mkdir()
        private.chmod(0o777)
    blocker = tmp_path / "a-file"
    env = _env(HOME=str(blocker / "home"), XDG_CACHE_HOME=str(blocker / "cache"), TMPDIR=str(tmp),
               PYTHONPATH=os.pathsep.join([str(mod), str(ROOT)]))
    env.pop("NUMBA_CACHE_DIR", None)
    blocker.write_text("")
    done = _python(tmp_path, "-c", "import jitted; print(jitted.twice(21))", env=env)
    assert (done.returncode, done.stdout, done.stderr) == (0, "42\n", "")
    cached = list(tmp_path.rglob("*.nbi"))
    assert [p.parent.parent for p in cached] == ([private] if fallback == "usable" else []), cached


# ------------------------------------------------------------------------------------- (C) file permissions
_WRITE_ALL = """
import sys
from pathlib import Path
import pbdyn
from pbdyn.metrics.cached import map_metrics
from pbdyn.world.maps import enumerate_maps
out = Path(sys.argv[1])
pbdyn.run_trial("quickstart", trace=out / "trace.npz", gui_snapshot=out / "final.png")
sc = pbdyn.load_scenario("quickstart")
pbdyn.rollout(sc, 0).save(out / "rollout.npz")
map_metrics(sc, enumerate_maps(sc)[0], ["density"])
"""


@pytest.mark.parametrize("umask", [0o022, 0o077, 0o002])
def test_outputs_and_caches_follow_the_umask(tmp_path, umask):
    """A trace, a snapshot, a rollout, and the rollout and metric caches get 0666 minus the umask."""
    out, cache = tmp_path / "out", tmp_path / "cache"
    out.mkdir()
    done = _python(ROOT, "-c", _WRITE_ALL, str(out), env=_env(PBDYN_CACHE=str(cache)), umask=umask)
    assert done.returncode == 0, done.stderr
    files = [*out.iterdir(), *cache.rglob("*.npz"), *cache.rglob("*.json")]
    assert {p.suffix for p in files} == {".npz", ".png", ".json"} and len(files) >= 5, files
    assert {p.name: oct(stat.S_IMODE(p.stat().st_mode)) for p in files} == {p.name: oct(0o666 & ~umask)
                                                                           for p in files}


def test_atomic_write_follows_the_umask(tmp_path):
    code = ("import sys; from pathlib import Path; from pbdyn.files import atomic_write; "
            "atomic_write(sys.argv[1], lambda tmp: Path(tmp).write_text('x'))")
    for umask in (0o027, 0o002):
        target = tmp_path / f"f{umask}.txt"
        done = _python(ROOT, "-c", code, str(target), umask=umask)
        assert done.returncode == 0, done.stderr
        assert stat.S_IMODE(target.stat().st_mode) == 0o666 & ~umask
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f2.txt", "f23.txt"]   # no temporary file left


# ----------------------------------------------------------------------------- (D) quiet workers, --gui
@pytest.mark.parametrize("workers", ["1", "2"])
def test_a_lockstep_batch_ends_quietly(tmp_path, workers):
    """Every stderr line of `pbdyn batch` is its own progress line: no PyBullet shutdown traceback from the
    workers' clients (BulletClient.__del__ at interpreter exit). `pbdyn evaluate` of its store, `pbdyn run
    quickstart` and `pbdyn metrics quickstart --map 0` print nothing at all on stderr, shutdown included."""
    done = _python(ROOT, "-m", "pbdyn", "batch", "quickstart", "--out", str(tmp_path / "r.sqlite"), "--limit", "20",
                   "--workers", workers)
    assert done.returncode == 0, done.stderr
    assert "20 run now, 0 errors" in done.stdout
    lines = done.stderr.splitlines()
    assert lines and all(ln.startswith("pbdyn batch: ") for ln in lines), done.stderr
    assert not any(word in done.stderr for word in ("Exception ignored", "Traceback", "Warning"))
    if workers == "1":    # the commands that read the store, and the everyday ones, leave stderr empty on success
        for args in (["evaluate", str(tmp_path / "r.sqlite")], ["run", "quickstart"],
                     ["metrics", "quickstart", "--map", "0"]):
            done = _python(tmp_path, "-m", "pbdyn", *args)
            assert done.returncode == 0 and done.stdout, (args, done.returncode, done.stderr)
            assert done.stderr == "", (args, done.stderr)


def test_a_reader_that_goes_away_ends_the_command_quietly(tmp_path):
    """stdout closed by its reader before pbdyn writes (`pbdyn run quickstart | head -0`): exit 141 (128 + SIGPIPE)
    and nothing on stderr, neither an internal error nor Python's "Exception ignored" at shutdown."""
    proc = subprocess.Popen([sys.executable, "-m", "pbdyn", "run", "quickstart"], cwd=tmp_path, env=_env(),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()
    err = proc.stderr.read()
    proc.stderr.close()
    assert (proc.wait(timeout=300), err) == (141, b"")


def test_gui_without_a_display_is_one_line_and_exit_2(tmp_path):
    env = _env()
    for name in ("DISPLAY", "WAYLAND_DISPLAY"):
        env.pop(name, None)
    done = _python(tmp_path, "-m", "pbdyn", "run", "quickstart", "--gui", env=env, timeout=120)
    assert done.returncode == 2 and done.stdout == "", (done.returncode, done.stdout, done.stderr)
    lines = done.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("pbdyn: error: --gui: ") and "DISPLAY" in lines[0], lines


def test_gui_with_an_unreachable_display_is_one_line_and_exit_2(tmp_path):
    env = _env()
    env["DISPLAY"] = ":987"                      # no X server: no socket /tmp/.X11-unix/X987
    done = _python(tmp_path, "-m", "pbdyn", "run", "quickstart", "--gui", env=env, timeout=120)
    assert done.returncode == 2 and done.stdout == "", (done.returncode, done.stdout, done.stderr)
    lines = done.stderr.splitlines()
    assert len(lines) == 1 and "--gui: cannot reach the X server of DISPLAY=':987'" in lines[0], lines
