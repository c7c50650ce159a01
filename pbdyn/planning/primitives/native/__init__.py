"""pbdyn's native ruckig batch: ruckig's trajectory calculator called from compiled code, many candidates per call.

The motion-primitive planners build most of their candidates through the ruckig Python package, one binding call
(plus setting its inputs and reading its profiles) per trajectory: ~9 us of Python around ~2 us of ruckig. When
the library built by ``python -m pbdyn.planning.primitives.native.build`` (`make` builds it) is present, matches the
installed ruckig version and gives, on a fixed probe of planner-like inputs, the very durations and profiles the Python
package gives (bit for bit), ruckig_build_address() hands its entry point to the compiled candidate search
(candidate_search.search); otherwise None, and the planners use the Python package: the same
trajectories, slower. PBDYN_NATIVE=0 in the environment turns the library off.

The build records the library's sha256 beside it (``_ruckig_batch.so.sha256``) after probing it in a subprocess; a
library whose bytes do not match that record (truncated, corrupted, replaced, or built without one) is never loaded,
since loading a damaged shared library can end the process with a signal. A library that is present but not used
is reported in one line on stderr, once per process tree (PBDYN_NATIVE_REPORTED passes the line to child processes).

The probe against the Python package (agrees) runs once per installed build and environment, not in every process:
a library that passed it leaves a stamp in pbdyn's cache folder (pbdyn.files.cache_dir, ``native/``) named by a
digest of what the result depends on -- the library's sha256, the ruckig version and the file of its Python
extension, the numpy and Python versions, the C library, the machine and its CPU's model and flags, and the probe
itself (agreement_key). A process that finds its stamp skips the probe; the integrity and version checks run every
time. Where the stamp cannot be written (no writable cache folder) every process probes, as before.
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import importlib.metadata
import importlib.util
import os
import platform
import sys
from pathlib import Path

import numpy as np

from pbdyn.files import atomic_write_text
from pbdyn.planning.primitives.compiled.ruckig_sampling import PROFILE_WIDTH, profile_row

_P = ctypes.c_void_p
LIBRARY = Path(__file__).resolve().parent / "_ruckig_batch.so"   # built by pbdyn.planning.primitives.native.build
_REPORTED = "PBDYN_NATIVE_REPORTED"


def checksum_path(path: Path) -> Path:
    """Where the build records the sha256 of the library at ``path``."""
    return path.with_name(path.name + ".sha256")


def write_checksum(path: Path) -> None:
    """Record the sha256 of the library at ``path`` beside it (atomically; sha256sum's format)."""
    atomic_write_text(checksum_path(path), f"{hashlib.sha256(path.read_bytes()).hexdigest()}  {path.name}\n")


def integrity_problem(path: Path) -> str | None:
    """Why the library at ``path`` must not be loaded (it does not match the sha256 its build recorded, or there
    is no record), or None."""
    return _integrity(path)[0]


def _integrity(path: Path) -> tuple[str | None, str]:
    """(integrity_problem(path), the library's sha256 when it matches its record, else "")."""
    try:
        recorded = checksum_path(path).read_text().split()[0]
    except (OSError, UnicodeDecodeError, IndexError):
        return ("has no valid checksum record beside it (rebuild it with "
                "`python -m pbdyn.planning.primitives.native.build`)", "")
    try:
        actual = hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError as exc:
        return f"cannot be read ({exc.strerror or exc})", ""
    if actual != recorded:
        return ("does not match the checksum its build recorded (truncated or corrupted; rebuild it with "
                "`python -m pbdyn.planning.primitives.native.build`)", "")
    return None, actual


def _report(problem: str) -> None:
    """One line on stderr: the library is not used, and why (not repeated by child processes)."""
    line = f"pbdyn: {LIBRARY} {problem}; planners use the ruckig Python package"
    if os.environ.get(_REPORTED) != line:
        print(line, file=sys.stderr, flush=True)
        os.environ[_REPORTED] = line


def _load(path) -> ctypes.CDLL:
    lib = ctypes.CDLL(str(path))
    lib.pbdyn_ruckig_version.restype = ctypes.c_char_p
    lib.pbdyn_ruckig_build.restype = ctypes.c_int
    lib.pbdyn_ruckig_build.argtypes = [ctypes.c_long, ctypes.c_long, _P, _P, _P, _P, _P, _P, ctypes.c_double,
                                       ctypes.c_double, _P, _P, _P]
    return lib


def probe_inputs(d: int, n: int, seed: int = 20261125) -> tuple:
    """n planner-like ruckig inputs for d axes (fixed seed): current velocity and acceleration, target position and
    velocity [n, d], velocity and acceleration limits [n]; some have zero components, some are rejected."""
    rng = np.random.default_rng(seed + d)
    cur_v = rng.normal(size=(n, d)) * rng.choice([0.0, 0.5, 2.0], size=(n, 1))
    cur_a = rng.normal(size=(n, d)) * rng.choice([0.0, 1.0, 5.0], size=(n, 1))
    tgt_p = rng.normal(size=(n, d)) * 3.0 * rng.choice([0.0, 0.3, 1.0, 3.0], size=(n, 1))
    tgt_v = rng.normal(size=(n, d)) * rng.choice([0.0, 1.0], size=(n, 1))
    return cur_v, cur_a, tgt_p, tgt_v, rng.uniform(0.5, 5.0, n), rng.uniform(0.5, 10.0, n)


def build_with_library(lib: ctypes.CDLL, inputs: tuple, jerk: float, min_duration: float) -> tuple:
    """(profiles [n, d, PROFILE_WIDTH], durations [n], result codes [n]) of ``inputs`` (probe_inputs' layout) from
    the native library (ctypes: for probes and tests; the planners call it from compiled code)."""
    cur_v, cur_a, tgt_p, tgt_v, lim_v, lim_a = (np.ascontiguousarray(x, dtype=float) for x in inputs)
    n, d = cur_v.shape
    prof = np.zeros((n, d, PROFILE_WIDTH))
    dur = np.zeros(n)
    res = np.zeros(n, dtype=np.int64)
    lib.pbdyn_ruckig_build(n, d, cur_v.ctypes.data, cur_a.ctypes.data, tgt_p.ctypes.data, tgt_v.ctypes.data,
                           lim_v.ctypes.data, lim_a.ctypes.data, float(jerk), float(min_duration), prof.ctypes.data,
                           dur.ctypes.data, res.ctypes.data)
    return prof, dur, res


def build_with_package_reference(inputs: tuple, jerk: float, min_duration: float) -> tuple:
    """build_with_library's outputs from the ruckig Python package: its reference twin (agrees() compares them bit
    for bit); result codes: 0 / 1 for Working / Finished, -1 for a rejected input."""
    import ruckig

    cur_v, cur_a, tgt_p, tgt_v, lim_v, lim_a = inputs
    n, d = cur_v.shape
    otg, traj, inp = ruckig.Ruckig(d), ruckig.Trajectory(d), ruckig.InputParameter(d)
    inp.current_position = [0.0] * d
    inp.target_acceleration = [0.0] * d
    inp.max_jerk = [float(jerk)] * d
    inp.minimum_duration = float(min_duration)
    prof = np.zeros((n, d, PROFILE_WIDTH))
    dur = np.zeros(n)
    res = np.full(n, -1, dtype=np.int64)
    for i in range(n):
        inp.current_velocity = cur_v[i].tolist()
        inp.current_acceleration = cur_a[i].tolist()
        inp.target_position = tgt_p[i].tolist()
        inp.target_velocity = tgt_v[i].tolist()
        inp.max_velocity = [float(lim_v[i])] * d
        inp.max_acceleration = [float(lim_a[i])] * d
        try:
            result = otg.calculate(inp, traj)
        except (ruckig.RuckigError, ValueError):
            continue
        if result in (ruckig.Result.Working, ruckig.Result.Finished):
            res[i] = 0 if result == ruckig.Result.Working else 1
            dur[i] = traj.duration
            prof[i] = np.array(profile_row(traj)).reshape(d, PROFILE_WIDTH)
    return canonical(prof), dur, res


def canonical(prof: np.ndarray) -> np.ndarray:
    """Profile rows [..., PROFILE_WIDTH] with the start state of an empty second brake phase (brake t[1] <= 0) set
    to zero: ruckig leaves it unset (stale from an earlier calculation) and no sample reads it. The library writes
    rows in this form."""
    out = prof.copy()
    empty = ~(out[..., 40] > 0.0)
    for col in (44, 46, 48):
        out[..., col] = np.where(empty, 0.0, out[..., col])
    return out


PROBE_N = 300
"""Inputs per dimension (2 and 3) of the probe against the Python package (agrees)."""
_PROBE = (20.0, 0.5)   # the probe's jerk limit and minimum duration
STAMP_VERSION = "1"
"""Version of the agreement stamp's key (agreement_key): bump it when what the probe covers changes."""


def agrees(lib: ctypes.CDLL, n: int = PROBE_N) -> bool:
    """True if the library gives the ruckig package's results bit for bit on probe_inputs (2D and 3D, n each):
    the same accepted inputs, durations and profiles."""
    for d in (2, 3):
        inputs = probe_inputs(d, n)
        prof, dur, res = build_with_library(lib, inputs, *_PROBE)
        ref_prof, ref_dur, ref_res = build_with_package_reference(inputs, *_PROBE)
        ok = (res == 0) | (res == 1)
        if not np.array_equal(ok, ref_res >= 0):
            return False
        if not (np.array_equal(dur[ok], ref_dur[ok]) and np.array_equal(prof[ok], ref_prof[ok])):
            return False
    return True


@functools.cache
def ruckig_build_address() -> int | None:
    """The address of the library's pbdyn_ruckig_build if it is present, intact, current and agrees with the
    ruckig package (module doc); None otherwise (a present but unusable library is reported once: _report)."""
    if os.environ.get("PBDYN_NATIVE", "1") == "0" or not LIBRARY.is_file():
        return None
    problem, digest = _integrity(LIBRARY)
    if problem is not None:
        _report(problem)
        return None
    try:
        lib = _load(LIBRARY)
        built_for = lib.pbdyn_ruckig_version().decode()
    except (OSError, AttributeError, UnicodeDecodeError) as exc:
        _report(f"cannot be loaded ({exc})")
        return None
    installed = importlib.metadata.version("ruckig")
    if built_for != installed:
        _report(f"was built for ruckig {built_for}, ruckig {installed} is installed (rebuild it with "
                "`python -m pbdyn.planning.primitives.native.build`)")
        return None
    stamp = agreement_stamp(digest, installed)
    if stamp is None or not stamp.is_file():
        if not agrees(lib):
            _report("differs from the ruckig Python package on this machine")
            return None
        if stamp is not None:
            _write_stamp(stamp, digest, installed)
    _KEEP.append(lib)
    return ctypes.cast(lib.pbdyn_ruckig_build, ctypes.c_void_p).value


_KEEP: list = []   # the loaded library stays referenced while its address is in use


def _cpu() -> str:
    """The CPU's model and feature flags as the system reports them (Linux: /proc/cpuinfo; else the platform's
    processor string)."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as fh:
            wanted = {}
            for line in fh:
                name, _, value = line.partition(":")
                name = name.strip()
                if name in ("model name", "flags", "Features", "CPU implementer", "CPU part") and name not in wanted:
                    wanted[name] = value.strip()
                elif not line.strip() and wanted:
                    break          # the first processor's block is enough
            return repr(sorted(wanted.items()))
    except OSError:
        return platform.processor()


def agreement_key(library_sha256: str, ruckig_version: str) -> str:
    """The digest naming the stamp of a library that passed agrees() (module doc): over the library's sha256, the
    ruckig version and its extension file (path, size, modification time), numpy's and Python's versions, the C
    library, the machine and CPU, and the probe (inputs, limits, STAMP_VERSION)."""
    spec = importlib.util.find_spec("ruckig")
    origin = getattr(spec, "origin", None) or ""
    try:
        st = os.stat(origin)
        ext = (origin, st.st_size, st.st_mtime_ns)
    except OSError:
        ext = (origin, None, None)
    libc = os.confstr("CS_GNU_LIBC_VERSION") if "CS_GNU_LIBC_VERSION" in getattr(os, "confstr_names", {}) else ""
    parts = (STAMP_VERSION, library_sha256, ruckig_version, ext, np.__version__, sys.version, sys.platform,
             platform.machine(), libc, _cpu(), PROBE_N, _PROBE, PROFILE_WIDTH)
    return hashlib.sha256(repr(parts).encode()).hexdigest()


def agreement_stamp(library_sha256: str, ruckig_version: str) -> Path | None:
    """Where the stamp of a library that passed agrees() here is (module doc); None if it cannot be named."""
    from pbdyn.files import cache_dir

    try:
        return cache_dir() / "native" / f"agrees-{agreement_key(library_sha256, ruckig_version)[:40]}"
    except (OSError, RuntimeError, ValueError):    # no home folder to find the cache in, ...
        return None


def _write_stamp(stamp: Path, library_sha256: str, ruckig_version: str) -> None:
    """Leave the stamp (atomically); quietly nothing where the cache cannot be written (every process probes)."""
    text = (f"{LIBRARY.name} sha256 {library_sha256} agrees with ruckig {ruckig_version} (numpy {np.__version__}, "
            f"Python {platform.python_version()}) on {PROBE_N} x 2 probe inputs\n")
    try:
        atomic_write_text(stamp, text, make_parents=True)
    except OSError:
        pass


def status() -> str:
    """One line: whether the planners build trajectories through the native library, and if not, why."""
    if os.environ.get("PBDYN_NATIVE", "1") == "0":
        return "native ruckig batch: off (PBDYN_NATIVE=0)"
    if not LIBRARY.is_file():
        return "native ruckig batch: not built (python -m pbdyn.planning.primitives.native.build)"
    return "native ruckig batch: " + ("in use" if ruckig_build_address() is not None else "present, not used")
