"""The batch runner (`pbdyn batch`): every trial and map metric of a scenario, in parallel, into a results store.

The coordinator (this process) enumerates the experiment, skips what the store already holds, builds each map's
rollout once (cached .npz files, shipped to workers by path; to Dask workers as bytes, scattered once per map),
submits trials and map-metric tasks to a process pool (spawn: no worker is ever forked from a process holding a
PyBullet client) or to a Dask cluster through its concurrent.futures executor, and is the only writer of the
store: rows are inserted with INSERT OR IGNORE and committed at least once a second, so killing the coordinator or
a worker loses no committed trial and a re-run completes the rest. A trial that raises becomes an "error" row.

Every row records its planner pair's fingerprint (pbdyn.planning.registry.pair_fingerprint) and its world's (the
first digits of its map's rollout key, which covers an imported world's URDFs, meshes and motion modules). A store
holding rows flown with other planner code, or in a world whose code or files changed, stops the batch before
anything runs, naming what changed, unless ``rerun_changed`` re-flies exactly those rows (a changed world's maps:
their old rows and metrics are deleted and the maps flown and measured again); ``retry_errors`` re-flies the
"error" rows. Re-flown rows replace the old ones row by row (INSERT OR
REPLACE). SIGTERM and SIGINT stop the batch: rows that have arrived are committed, the worker processes are
terminated, and BatchInterrupted (a KeyboardInterrupt; exit status 128 + signal number) is raised.
"""

from __future__ import annotations

import collections
import concurrent.futures as cf
import queue as queue_module
import contextlib
import itertools
import multiprocessing
import os
import signal
import sqlite3
import sys
import threading
import time
from collections.abc import Iterator
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, replace
from pathlib import Path

from pbdyn import __version__
from pbdyn.config import Scenario, canonical_json
from pbdyn.errors import ConfigError, PbdynError, one_line
from pbdyn.experiments.mainguard import MainGuardError, PoolGuard, check_not_reimported
from pbdyn.experiments.store import WORLD_FINGERPRINT_CHARS, ResultsStore, check_store_path, store_error
from pbdyn.experiments.tasks import (METRIC_SET, MapTask, RolloutRef, TrialGroupTask, TrialTask, enumerate_trials,
                                     run_map_task, run_trial_group_task, run_trial_task, trial_spec, worker_init)
from pbdyn.world.rollout import default_horizon, rollout_file

COMMIT_INTERVAL_S = 1.0
LOCKSTEP_TRIALS = 72
"""Default most trials of one map flown together per task (one planner pair's start/goal pairs at one speed)."""
MAX_POOL_RESTARTS = 3
CONNECT_TIMEOUT_S = 10.0


@dataclass(frozen=True)
class BatchOptions:
    """workers: local processes (default: CPU count); scheduler: a Dask scheduler address ("tcp://host:8786") or
    a dask.distributed Client; limit: fly only the first N trials of the enumeration; extend: accept a scenario
    that adds grid values, planners, MAV speeds or maps to the one in the store; metrics: compute each map's
    metrics (METRIC_SET); progress: a progress line on stderr; rerun_changed: re-fly stored rows whose planner
    fingerprint differs from the current code's, and the maps whose world changed (else such rows stop the batch);
    retry_errors: re-fly stored "error" rows."""

    workers: int | None = None
    scheduler: object = None
    limit: int | None = None
    extend: bool = False
    metrics: bool = True
    progress: bool = True
    rerun_changed: bool = False
    retry_errors: bool = False
    lockstep: int = LOCKSTEP_TRIALS
    shard: tuple[int, int] | None = None


@dataclass(frozen=True)
class BatchSummary:
    """What a batch run did: trials in the experiment (after --limit), already stored (and kept), run now (rerun of
    them replaced stored rows), this run's error rows, maps whose metrics were computed, and the error rows the
    store holds after the run."""

    total: int
    skipped: int
    ran: int
    errors: int
    maps_computed: int
    wall_time_s: float
    rerun: int = 0
    stored_errors: int = 0


class BatchInterrupted(KeyboardInterrupt):
    """SIGTERM or SIGINT stopped a batch; committed rows are kept. ``exit_status`` = 128 + the signal number."""

    def __init__(self, signum: int, message: str = ""):
        self.signum = signum
        self.exit_status = 128 + signum
        super().__init__(message or f"stopped by {signal.Signals(signum).name}")


@contextlib.contextmanager
def _stop_on_signals() -> Iterator[None]:
    """Within the block, the first SIGTERM or SIGINT raises BatchInterrupted (later ones are ignored while the
    batch cleans up); the previous handlers are restored after it. A no-op outside the main thread."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    fired: list[int] = []

    def handler(signum, frame):
        if not fired:
            fired.append(signum)
            raise BatchInterrupted(signum)

    old = {sig: signal.signal(sig, handler) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        yield
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)


# ------------------------------------------------------------------------------------------------ --extend
_GROWABLE = {("obstacles", "count"), ("obstacles", "radius"), ("obstacles", "speed"), ("drone", "v_max"),
             ("planners",), ("obstacles", "maps")}


def _diff(old, new, path=()) -> Iterator[tuple[tuple, object, object]]:
    if isinstance(old, dict) and isinstance(new, dict):
        for k in sorted(set(old) | set(new)):
            yield from _diff(old.get(k), new.get(k), path + (k,))
    elif old != new:
        yield path, old, new


def scenario_changes(old: dict, new: dict) -> tuple[list[str], list[str]]:
    """(allowed, refused) changes from the stored resolved scenario ``old`` to ``new``: grid values, planners and
    MAV speeds may be added (old ones kept, in order), maps_per_setup may grow; anything else is refused."""
    allowed, refused = [], []
    for path, a, b in _diff(old, new):
        name = ".".join(map(str, path))
        if path in _GROWABLE and isinstance(a, list) and isinstance(b, list) \
                and [canonical_json(x) for x in b[:len(a)]] == [canonical_json(x) for x in a]:
            allowed.append(name)
        elif path == ("obstacles", "maps_per_setup") and isinstance(a, int) and isinstance(b, int) and b > a:
            allowed.append(name)
        else:
            refused.append(name)
    return allowed, refused


def check_scenario(store: ResultsStore, scenario: Scenario, extend: bool, write: bool = True) -> None:
    """Record the scenario in a new store; for an existing one require the same scenario, or with ``extend`` only
    additions (ConfigError naming SCENARIO otherwise). ``write=False``: check only."""
    doc = {"name": scenario.name, **scenario.to_dict()}
    new_json = canonical_json(doc)
    old_json = store.get_meta("scenario")
    if old_json is None:
        if write:
            store.set_meta("scenario", new_json)
        return
    if old_json == new_json:
        return
    import json

    old = json.loads(old_json)
    old_profile = old.get("profile", "physical")
    if old_profile != scenario.profile:
        raise ConfigError("SCENARIO", f"has profile {scenario.profile!r} but {store.path.name} holds "
                          f"{old_profile!r} rows; a store holds one profile (use a new --out file)",
                          scenario.source or scenario.name)
    allowed, refused = scenario_changes(old, doc)
    if refused:
        raise ConfigError("SCENARIO", f"differs from the scenario {store.path.name} was made with in "
                          f"{', '.join(refused)}; --extend only accepts added grid values, planners, MAV speeds or "
                          "maps (use a new --out file)", scenario.source or scenario.name)
    if not extend:
        raise ConfigError("SCENARIO", f"adds to the scenario {store.path.name} was made with ({', '.join(allowed)});"
                          " pass --extend to run the additions", scenario.source or scenario.name)
    if write:
        store.set_meta("scenario", new_json)


# ------------------------------------------------------------------------------------------------ progress
class Progress:
    """A progress line on stderr: done/total, trials per second and ETA; per finished trial on a terminal, every
    5 s otherwise."""

    def __init__(self, total: int, enabled: bool):
        self.total, self.enabled = total, enabled and total > 0
        self.done = 0
        self.t0 = time.perf_counter()
        self.tty = sys.stderr.isatty()
        self.last = 0.0

    def step(self, n: int = 1) -> None:
        self.done += n
        if not self.enabled:
            return
        now = time.perf_counter()
        if self.tty or now - self.last >= 5.0 or self.done == self.total:
            self.last = now
            rate = self.done / max(now - self.t0, 1e-9)
            eta = (self.total - self.done) / rate if rate > 0 else float("inf")
            line = f"pbdyn batch: {self.done}/{self.total} trials, {rate:.2f}/s, ETA {_fmt_s(eta)}"
            sys.stderr.write(("\r" + line) if self.tty else line + "\n")
            if self.tty and self.done == self.total:
                sys.stderr.write("\n")
            sys.stderr.flush()


def _fmt_s(s: float) -> str:
    if s == float("inf"):
        return "?"
    s = int(round(s))
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}"


# ------------------------------------------------------------------------------------------------ executors
class _Pool:
    """A process pool (spawn context, BLAS/OpenMP threads = 1 in workers) or a Dask client's executor."""

    def __init__(self, workers: int, scheduler):
        self.client = None
        self.own_client = False
        self.workers = workers
        self.guard = None           # local pools: a worker re-importing a main script without its guard reports here
        if scheduler is not None:
            self.client = connect(scheduler) if isinstance(scheduler, str) else scheduler
            self.own_client = isinstance(scheduler, str)
            self.executor = self.client.get_executor(pure=False)
            self.scattered: dict[str, object] = {}
            self.queue = None               # Dask: rows come with each group's result
        else:
            self._start()

    def _start(self) -> None:
        for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
            os.environ.setdefault(var, "1")
        if self.guard is None:
            self.guard = PoolGuard("run_batch")
        ctx = multiprocessing.get_context("spawn")
        self.queue = ctx.Queue()        # rows of lockstep groups, sent by the workers as each trial ends
        self.executor = cf.ProcessPoolExecutor(max_workers=self.workers, initializer=worker_init,
                                               initargs=(self.queue,), mp_context=ctx)

    def rows(self) -> Iterator[tuple]:
        """The rows the workers have sent so far through the queue (none for Dask: they come with each result)."""
        while self.queue is not None:
            try:
                yield self.queue.get_nowait()
            except queue_module.Empty:
                return
            except (OSError, EOFError, ValueError):   # a worker died while writing: its rows come again
                return

    @property
    def dask(self) -> bool:
        return self.client is not None

    def check_broken(self) -> None:
        """After the pool broke: MainGuardError if a worker died re-importing a main script that calls run_batch at
        its top level (pbdyn.experiments.mainguard): restarting would only break it again."""
        if self.guard is not None:
            self.guard.check()

    def restart(self) -> None:
        self.executor.shutdown(wait=False, cancel_futures=True)
        self.queue.close()
        self._start()

    def submit(self, fn, task, key: str, path: Path):
        """Submit fn(task) -- for Dask fn(task, data) with the rollout's bytes scattered once per map."""
        if not self.dask:
            return self.executor.submit(fn, task)
        if key not in self.scattered:
            self.scattered[key] = self.client.scatter(path.read_bytes(), broadcast=True)
        return self.executor.submit(fn, task, self.scattered[key])

    def close(self, terminate: bool = False) -> None:
        """Shut down: wait for running tasks, or with ``terminate`` cancel them and end the local worker processes
        (SIGTERM, then SIGKILL after 5 s); a Dask cluster's workers are left running."""
        if self.dask:
            self.executor.shutdown(wait=not terminate)     # wait=False cancels the running futures
        elif terminate:
            procs = list((getattr(self.executor, "_processes", None) or {}).values())
            for p in procs:
                p.terminate()
            self.executor.shutdown(wait=False, cancel_futures=True)
            for p in procs:
                p.join(5.0)
                if p.is_alive():
                    p.kill()
                    p.join(1.0)
        else:
            self.executor.shutdown(wait=True, cancel_futures=True)
        if self.guard is not None:
            self.guard.close()
        if self.own_client:
            self.client.close()


def check_planners(scenario: Scenario) -> None:
    """Resolve and build every planner entry once (names, plug-in imports, parameters), so that a bad entry is one
    clear error before the batch starts rather than an "error" row for each of its trials."""
    import numpy as np

    from pbdyn.planning.protocols import PlannerContext
    from pbdyn.planning.registry import build_planner, resolve_gaze_planner, resolve_trajectory_planner
    from pbdyn.planning.view import MAVLimits

    d = scenario.drone
    for v in d.v_max:
        ctx = PlannerContext(scenario.world.dims, scenario.world.dt, MAVLimits(d.radius, v, d.a_max, d.yaw_rate_limit),
                             np.zeros(scenario.world.dims), np.asarray(scenario.world.size, dtype=float), 0)
        for i, e in enumerate(scenario.planners):
            build_planner(resolve_trajectory_planner(e.trajectory, f"planners[{i}].trajectory"), ctx,
                          e.trajectory_params, f"planners[{i}].trajectory_params")
            build_planner(resolve_gaze_planner(e.gaze, f"planners[{i}].gaze"), ctx, e.gaze_params,
                          f"planners[{i}].gaze_params")


SCHEMES = ("tcp", "tls", "inproc", "ucx")
PROBE_TIMEOUT_S = 3.0
"""How long a scheduler address may take to send Dask's handshake after accepting a connection."""
_MAX_HANDSHAKE = 1 << 24


def _scheduler_error(problem: str, address: str) -> ConfigError:
    return ConfigError("scheduler", problem, address)


def parse_scheduler(address: str) -> tuple[str, str, int | None]:
    """(scheme, host, port) of a Dask scheduler address "SCHEME://HOST:PORT" (scheme tcp, tls, inproc or ucx;
    "HOST:PORT" means tcp); ConfigError naming --scheduler otherwise."""
    from urllib.parse import urlsplit

    if not isinstance(address, str) or not address.strip():
        raise _scheduler_error("must be a Dask scheduler address like tcp://host:8786", address)
    text = address.strip()
    if "://" not in text:
        text = "tcp://" + text
    try:
        u = urlsplit(text)
        port = u.port
    except ValueError as exc:
        raise _scheduler_error(f"is not an address like tcp://host:8786 ({exc})", address) from None
    scheme = u.scheme.lower()
    if scheme in ("http", "https"):
        raise _scheduler_error("is an HTTP address; give the scheduler's own address, like tcp://host:8786 (the "
                               "dashboard on :8787 is not the scheduler)", address)
    if scheme not in SCHEMES:
        raise _scheduler_error(f"has scheme {scheme!r}; use one of {', '.join(s + '://' for s in SCHEMES)}", address)
    if scheme == "inproc":
        return scheme, text[len("inproc://"):], None
    if u.path not in ("", "/") or u.query or u.fragment or u.username or u.password:
        raise _scheduler_error("must be SCHEME://HOST:PORT with nothing after the port", address)
    if not u.hostname:
        raise _scheduler_error("has no host (like tcp://host:8786)", address)
    if port is None or not 1 <= port <= 65535:
        raise _scheduler_error("needs a port in 1..65535 (like tcp://host:8786)", address)
    return scheme, u.hostname, port


def _in_thread(fn, timeout: float):
    """fn() in a daemon thread: ("ok", value), ("error", exception) or ("timeout", None) after ``timeout`` s (the
    thread is then abandoned; it cannot block the process' exit)."""
    box: list = []

    def target():
        try:
            box.append(("ok", fn()))
        except BaseException as exc:  # noqa: BLE001 - handed to the caller
            box.append(("error", exc))

    t = threading.Thread(target=target, name="pbdyn-connect", daemon=True)
    t.start()
    t.join(timeout)
    return box[0] if box else ("timeout", None)


def _probe(host: str, port: int, timeout: float) -> str | None:
    """None if a Dask comm listens at host:port (it sends the first frame of its handshake, an 8-byte length and
    a small message, as soon as it accepts), else what is wrong, in words."""
    import socket
    import struct

    try:
        sock = socket.create_connection((host, port), timeout=timeout)
    except socket.gaierror as exc:
        return f"cannot resolve the host ({exc.strerror or exc})"
    except (TimeoutError, socket.timeout):
        return f"no answer to a connection within {timeout:g} s"
    except OSError as exc:
        return f"cannot connect ({exc.strerror or exc})"
    with sock:
        deadline = time.monotonic() + timeout
        head = b""
        try:
            while len(head) < 8:
                sock.settimeout(max(0.01, deadline - time.monotonic()))
                chunk = sock.recv(8 - len(head))
                if not chunk:
                    return "the peer closed the connection without a Dask handshake"
                head += chunk
        except (TimeoutError, socket.timeout):
            what = _http_reply(sock)
            return (f"accepts connections but sent no Dask handshake within {timeout:g} s"
                    + (" (it answers HTTP: a web server, perhaps the dashboard, not the scheduler port)" if what else
                       " (not a Dask scheduler?)"))
        except OSError as exc:
            return f"the connection failed ({exc.strerror or exc})"
        if head[:4] in (b"HTTP", b"SSH-") or head[:1] == b"<":
            return f"answers like another protocol ({head[:8]!r}), not a Dask scheduler"
        (n,) = struct.unpack("<Q", head)
        if not 0 < n <= _MAX_HANDSHAKE:
            return f"sent a frame of {n} bytes where Dask's handshake is a small message (not a Dask scheduler?)"
    return None


def _http_reply(sock) -> bool:
    """After a silent wait: does the peer answer an HTTP request (with "HTTP/") within 0.5 s?"""
    try:
        sock.settimeout(0.5)
        sock.sendall(b"GET / HTTP/1.0\r\nHost: pbdyn\r\n\r\n")
        return sock.recv(5) == b"HTTP/"
    except OSError:
        return False


def connect(address: str, timeout: float | None = None):
    """A dask.distributed Client of the scheduler at ``address``. The address is checked (scheme tcp, tls, inproc
    or ucx; host; port 1..65535); a tcp address is probed first (a Dask comm sends its handshake on accept: a
    silent port or a web server is refused without handing it to dask, whose own timeout does not cover a peer
    that never answers); the Client is then created under an overall deadline. ``timeout``: seconds (default
    CONNECT_TIMEOUT_S). Every failure is a one-line ConfigError naming --scheduler; tls:// needs a
    dask.distributed Security object, so it is only accepted as a Client (run_batch(scheduler=Client(...)))."""
    timeout = CONNECT_TIMEOUT_S if timeout is None else float(timeout)
    scheme, host, port = parse_scheduler(address)
    if scheme == "tls":
        raise _scheduler_error("tls:// needs TLS certificates (a dask.distributed Security object), which a command "
                               "line address cannot carry: create the Client in Python and pass it, "
                               "pbdyn.run_batch(..., scheduler=Client(address, security=Security(...)))", address)
    t0 = time.monotonic()
    if scheme == "tcp":
        status, why = _in_thread(lambda: _probe(host, port, min(PROBE_TIMEOUT_S, timeout)), timeout)
        if status == "timeout":
            why = f"no answer within {timeout:g} s (host name lookup or connection hangs)"
        elif status == "error":
            why = one_line(why)
        if why:
            raise _scheduler_error(f"cannot reach a Dask scheduler there: {why}", address)
    left = max(1.0, timeout - (time.monotonic() - t0))
    target = f"{scheme}://{host}:{port}" if scheme != "inproc" else address.strip()

    def make():
        from dask.distributed import Client

        return Client(target, timeout=left)

    status, value = _in_thread(make, left + 2.0)
    if status == "ok":
        return value
    if status == "timeout":
        raise _scheduler_error(f"cannot reach a Dask scheduler there: no client connection within {left + 2.0:g} s",
                               address)
    raise _scheduler_error(f"cannot reach a Dask scheduler there ({one_line(value)[:200]})", address)


MAX_WORKERS_PER_CPU = 4


def max_workers() -> int:
    """The largest --workers accepted: MAX_WORKERS_PER_CPU x the CPU count (more processes than that only add
    memory and switching; each worker holds a PyBullet client and a map's rollout)."""
    return MAX_WORKERS_PER_CPU * max(1, os.cpu_count() or 1)


def _default_workers() -> int:
    return max(1, os.cpu_count() or 1)


def changed_planners(store: ResultsStore, scenario: Scenario) -> tuple[dict[str, str], list[str]]:
    """(label -> the current code's fingerprint of every entry whose stored rows were flown with other code, one
    note per such entry: "planners[i] (label): n stored trials flown with <old>, the code now gives <new>").
    Counted in SQL: no stored key is read."""
    from pbdyn.planning.registry import pair_fingerprint

    current = {e.label: (i, pair_fingerprint(e.trajectory, e.gaze)) for i, e in enumerate(scenario.planners)}
    seen: dict[str, tuple[int, set[str]]] = {}
    for label, fp, n in store.fingerprint_counts():
        if label in current and fp != current[label][1]:
            k, fps = seen.get(label, (0, set()))
            seen[label] = (k + n, fps | {fp or "none"})
    notes = [f"planners[{current[label][0]}] ({label}): {n} stored trials flown with {', '.join(sorted(fps))}, the "
             f"code now gives {current[label][1]}" for label, (n, fps) in sorted(seen.items(),
                                                                                 key=lambda kv: current[kv[0]][0])]
    return {label: current[label][1] for label in seen}, notes


@dataclass
class _Plan:
    """What a batch will do, worked out before the store is written: pending trial count, rows it replaces, the
    maps whose rollouts the run needs, the maps whose metrics it computes."""

    start: int           # the trials start..start+total-1 of the enumeration (a shard, or all from 0)
    total: int
    pending: int
    rerun: int
    trial_maps: list
    metric_maps: list
    stored: bool          # the store holds trials: pending trials are looked up in it
    stale: dict           # label -> current fingerprint of entries whose rows must be re-flown (rerun_changed)
    worlds: dict = None   # map_id -> world fingerprint (rollout key prefix) of every map of the run's range
    stale_maps: frozenset = frozenset()   # maps whose stored rows were flown in another world (rerun_changed)


def shard_range(trials, total: int, shard: tuple[int, int] | None) -> tuple[int, int, range]:
    """(start, stop, map indices) of shard (i, n) of the first ``total`` trials: the maps they touch are cut into n
    contiguous blocks of (nearly) equal size and shard i takes the i-th block with all of its trials (a map's trials
    and its metrics stay in one shard; a shard can be empty when n exceeds the maps). None: everything."""
    maps = trials.map_range(total)
    if shard is None:
        return 0, total, maps
    i, n = shard
    m_lo, m_hi = (i - 1) * len(maps) // n, i * len(maps) // n
    per = trials.per_map
    return min(m_lo * per, total), min(m_hi * per, total), range(m_lo, m_hi)


def parse_shard(text) -> tuple[int, int]:
    """"I/N" (1 <= I <= N) -> (I, N); ConfigError naming --shard otherwise."""
    if isinstance(text, tuple) and len(text) == 2:
        i, n = text
    else:
        parts = str(text).split("/")
        try:
            i, n = (int(p) for p in parts) if len(parts) == 2 else (None, None)
        except ValueError:
            i = n = None
    if not (isinstance(i, int) and isinstance(n, int) and not isinstance(i, bool) and not isinstance(n, bool)
            and 1 <= i <= n):
        raise ConfigError("--shard", "must be I/N with integers 1 <= I <= N (e.g. 3/8)", text)
    return i, n


def _pending(trials, start: int, stop: int, states_of, stale: dict,
             retry_errors: bool, stale_maps: frozenset = frozenset()) -> Iterator[tuple[tuple, bool]]:
    """(trial, replaces a stored row) for every trial start..stop-1 that is not stored, or is stored and must be
    re-flown (its planner code or its map's world changed); ``states_of(keys)`` reads the stored states of a chunk
    of keys (None: nothing stored)."""
    it = trials.iter_range(start, stop)
    while True:
        chunk = list(itertools.islice(it, 500))
        if not chunk:
            return
        states = states_of([t[0] for t in chunk]) if states_of is not None else {}
        for t in chunk:
            st = states.get(t[0])
            if t[1].map_id in stale_maps:
                yield t, st is not None
            elif st is None:
                yield t, False
            else:
                label, fp, outcome = st
                if (label in stale and fp != stale[label]) or (retry_errors and outcome == "error"):
                    yield t, True


def _read_plan(out: Path, scenario: Scenario, trials, total: int, options: BatchOptions) -> _Plan:
    """Read the existing store (if any) read-only and work out the plan; refuse a changed scenario or changed
    planner code here, before anything is built or written."""
    start, stop, map_idx = shard_range(trials, total, options.shard)
    total = stop - start
    per_map_maps = [trials.maps[i] for i in map_idx]
    worlds = world_fingerprints(scenario, per_map_maps)
    if not out.exists() or out.stat().st_size == 0:
        return _Plan(start, total, total, 0, per_map_maps, per_map_maps if options.metrics else [], False, {},
                     worlds)
    store = ResultsStore.open(out, field="out")
    try:
        if store._foreign_tables():
            raise ConfigError("out", "is an SQLite file but not a pbdyn results store (use a new --out file)",
                              str(out))
        stale, notes = changed_planners(store, scenario)
        if stale and not options.rerun_changed:
            raise ConfigError("; ".join(notes), "planner code changed since these rows were flown; pass "
                              "--rerun-changed to re-fly them (or use a new --out file)", show_value=False)
        check_scenario(store, scenario, options.extend, write=False)
        stale_maps, world_notes = changed_worlds(store, scenario, per_map_maps, worlds)
        if stale_maps and not options.rerun_changed:
            raise ConfigError("; ".join(world_notes), "a world's code or files changed since these rows were "
                              "flown; pass --rerun-changed to re-fly those maps (or use a new --out file)",
                              show_value=False)
        if not options.rerun_changed:
            stale = {}
        stored = store.count() > 0
        pending = rerun = 0
        maps: dict[str, object] = {}
        for t, rep in _pending(trials, start, stop, store.stored_states if stored else None, stale,
                               options.retry_errors, stale_maps):
            pending += 1
            rerun += rep
            maps.setdefault(t[1].map_id, t[1])
        done = (store.maps_with_metrics() - stale_maps) if options.metrics else set()
        metric_maps = [m for m in per_map_maps if m.map_id not in done] if options.metrics else []
        return _Plan(start, total, pending, rerun, list(maps.values()), metric_maps, stored, stale, worlds,
                     stale_maps)
    finally:
        store.conn.close()


def world_fingerprints(scenario: Scenario, maps: list) -> dict[str, str]:
    """map_id -> world fingerprint of each map: the first WORLD_FINGERPRINT_CHARS hex digits of its rollout key,
    which covers everything its obstacles' motion depends on (settings, seed, the rollout model's version, an
    imported world's URDF, mesh and motion-module digests)."""
    from pbdyn.experiments.store import WORLD_FINGERPRINT_CHARS
    from pbdyn.world.rollout import rollout_key

    horizon = default_horizon(scenario)
    return {m.map_id: rollout_key(scenario, m, horizon)[:WORLD_FINGERPRINT_CHARS] for m in maps}


def changed_worlds(store: ResultsStore, scenario: Scenario, maps: list,
                   worlds: dict[str, str]) -> tuple[frozenset, list[str]]:
    """(map ids of ``maps`` whose stored trials or metrics were made in another world than the current code and
    files give, notes naming them and what changed). Rows stored before world fingerprints were recorded (schema
    < 4) are judged by their map's stored rollout key where the store has one."""
    import json

    from pbdyn.world.rollout import world_changes, world_description

    stored = store.world_fingerprints()
    changed = []
    for m in maps:
        got = stored.get(m.map_id)
        if got and any(fp and fp != worlds[m.map_id] for fp in got):
            changed.append((m, sum(got.values())))
    if not changed:
        return frozenset(), []
    old = store.get_meta("world")
    what = world_changes(json.loads(old), world_description(scenario), scenario) if old else []
    because = f" ({'; '.join(what)} changed)" if what else ""
    shown = ", ".join(f"{m.index} ({m.map_id}, {n} trials)" for m, n in changed[:5])
    more = f" and {len(changed) - 5} more" if len(changed) > 5 else ""
    return frozenset(m.map_id for m, _ in changed), [
        f"the world of map(s) {shown}{more} differs from the one their stored rows were flown in{because}"]


def run_batch(scenario: Scenario, out: str | Path, options: BatchOptions = BatchOptions(),
              command: str = "") -> BatchSummary:
    """Run (or resume, or extend) the experiment of ``scenario`` into the results store ``out``. SIGTERM/SIGINT
    raise BatchInterrupted after committing what has arrived and stopping the workers.

    Everything that can fail before the first trial -- options, planners, the store's compatibility, every needed
    rollout, the scheduler -- is done before the store is written, so a failed start leaves no new store file
    and an existing store untouched. The trials are enumerated lazily (--limit N costs O(N)). Called at the top
    level of a script without ``if __name__ == "__main__":`` (which every spawned worker runs again), it fails with
    one line, MainGuardError (pbdyn.experiments.mainguard), instead of restarting its workers over and over."""
    check_not_reimported("run_batch")
    t0 = time.perf_counter()
    workers = options.workers if options.workers is not None else _default_workers()
    if not isinstance(workers, int) or isinstance(workers, bool) or workers < 1:
        raise ConfigError("workers", "must be an integer >= 1", workers)
    if workers > max_workers():
        raise ConfigError("workers", f"must be <= {max_workers()} ({MAX_WORKERS_PER_CPU} x the "
                          f"{os.cpu_count() or 1} CPUs of this machine)", workers)
    if options.limit is not None and (not isinstance(options.limit, int) or isinstance(options.limit, bool)
                                      or options.limit < 1):
        raise ConfigError("limit", "must be an integer >= 1", options.limit)
    if not isinstance(options.lockstep, int) or isinstance(options.lockstep, bool) or options.lockstep < 1:
        raise ConfigError("lockstep", "must be an integer >= 1", options.lockstep)
    if options.shard is not None:
        options = replace(options, shard=parse_shard(options.shard))
    out_path = check_store_path(out, "out")
    check_planners(scenario)
    trials = enumerate_trials(scenario)
    total = len(trials) if options.limit is None else min(options.limit, len(trials))
    if isinstance(options.scheduler, str):   # reach the cluster before touching the store
        client = connect(options.scheduler)
        try:
            return run_batch(scenario, out, replace(options, scheduler=client), command)
        finally:
            client.close()
    with _stop_on_signals():
        plan = _read_plan(out_path, scenario, trials, total, options)
        files = _rollout_files(scenario, plan.trial_maps + plan.metric_maps, out_path)
        existed = out_path.exists()
        store = ResultsStore.create(out_path, field="out")
        remove = False
        try:
            return _run(store, scenario, trials, plan, files, workers, options, command, t0)
        except BatchInterrupted as exc:
            store.commit()
            raise BatchInterrupted(exc.signum, f"batch stopped by {signal.Signals(exc.signum).name}: {store.count()} "
                                   f"trials committed to {out} (re-run the same command to resume)") from None
        except MainGuardError:
            remove = not existed and store.count() == 0      # the workers never started: leave no new store
            raise
        except sqlite3.DatabaseError as exc:
            raise store_error("out", exc, out) from None
        finally:
            try:
                store.close()
            except ConfigError:
                pass
            if remove:
                for suffix in ("", "-wal", "-shm", "-journal"):
                    Path(str(out_path) + suffix).unlink(missing_ok=True)


def _rollout_files(scenario: Scenario, maps: list, out: Path) -> dict[str, tuple[str, Path]]:
    """map_id -> (rollout key, .npz path) of every map, built (or found in the cache) now."""
    horizon = default_horizon(scenario)
    files: dict[str, tuple[str, Path]] = {}
    for m in maps:
        if m.map_id not in files:
            files[m.map_id] = rollout_file(scenario, m, horizon, fallback_dir=out.absolute().parent)
    return files


def _run(store: ResultsStore, scenario: Scenario, trials, plan: _Plan, files: dict, workers: int,
         options: BatchOptions, command: str, t0: float) -> BatchSummary:
    from pbdyn.world.rollout import world_description

    check_scenario(store, scenario, options.extend)
    if plan.stale_maps:          # rows of another world go before any row of the current one is added
        store.drop_maps(plan.stale_maps)
    store.set_meta("world", canonical_json(world_description(scenario)))
    run_id = store.start_run(__version__, canonical_json(scenario.to_dict()), command,
                             "dask" if options.scheduler is not None else str(workers))
    ran = errors = maps_done = 0
    if plan.pending or plan.metric_maps:
        items = _pending(trials, plan.start, plan.start + plan.total, store.stored_states if plan.stored else None,
                         plan.stale, options.retry_errors, plan.stale_maps)
        ran, errors, maps_done = _execute(store, scenario, items, plan, files, workers, options)
    store.end_run(run_id)
    return BatchSummary(plan.total, plan.total - plan.pending, ran, errors, maps_done, time.perf_counter() - t0,
                        rerun=plan.rerun, stored_errors=store.error_count())


def _execute(store: ResultsStore, scenario: Scenario, items: Iterator, plan: _Plan, files: dict, workers: int,
             options: BatchOptions) -> tuple[int, int, int]:
    """Fly the pending ``items`` ((trial, replaces) pairs, streamed) and compute plan.metric_maps: a map's metrics
    are queued when the stream reaches its first trial (maps without pending trials first), at most a window of
    tasks is in flight, and a pool whose worker died is restarted with the lost tasks queued again."""
    pool = _Pool(workers, options.scheduler)
    progress = Progress(plan.pending, options.progress)
    counts = {"ran": 0, "errors": 0, "maps": 0}
    metric_ids = {m.map_id for m in plan.metric_maps}
    trial_map_ids = {m.map_id for m in plan.trial_maps}

    def source() -> Iterator[tuple]:
        return _grouped(maps_and_trials(), options.lockstep)

    def maps_and_trials() -> Iterator[tuple]:
        for m in plan.metric_maps:
            if m.map_id not in trial_map_ids:
                metric_ids.discard(m.map_id)
                yield "map", m, False
        for t, rep in items:
            if t[1].map_id in metric_ids:
                metric_ids.discard(t[1].map_id)
                yield "map", t[1], False
            yield "trial", t, rep
        for m in plan.metric_maps:          # metric maps the stream never reached (nothing pending there)
            if m.map_id in metric_ids:
                metric_ids.discard(m.map_id)
                yield "map", m, False

    streamed: dict = {}       # key -> (replaces, taken) of every trial of the lockstep groups in flight

    def world_of(row: dict) -> str | None:
        mid = row.get("map_id")
        fp = (plan.worlds or {}).get(mid)
        if fp is None and mid in files:
            fp = files[mid][0][:WORLD_FINGERPRINT_CHARS]
        return fp

    def store_row(key: str, row: dict, err, replace_row: bool) -> None:
        store.add_trials([(key, row, err)], replace=replace_row, world=world_of(row))
        counts["ran"] += 1
        counts["errors"] += err is not None
        progress.step()
        maybe_commit()

    def take_row(key: str, row: dict, err) -> None:
        """Store one row of a lockstep group (streamed or with its group's result), once."""
        state = streamed.get(key)
        if state is None or state[1]:
            return
        streamed[key] = (state[0], True)
        store_row(key, row, err, state[0])

    def drain() -> None:
        for key, row, err in pool.rows():
            take_row(key, row, err)

    def take(item, result) -> None:
        kind, obj, rep = item
        if kind == "map":
            store.add_map(result)
            counts["maps"] += 1
        elif kind == "group":
            for key, row, err in result:
                take_row(key, row, err)
            for t in obj:
                streamed.pop(t[0], None)
        else:
            store_row(*result, rep)

    stream = source()
    retry: collections.deque = collections.deque()
    in_flight: dict = {}
    last_commit = [time.perf_counter()]

    def maybe_commit() -> None:
        now = time.perf_counter()
        if now - last_commit[0] >= COMMIT_INTERVAL_S:
            store.commit()
            last_commit[0] = now
    restarts = 0
    interrupted = False
    window = (4 if options.lockstep <= 1 else 2) * workers if not pool.dask else max(64, 8 * workers)
    try:
        while True:
            try:
                while True:
                    while len(in_flight) < window:
                        item = retry.popleft() if retry else next(stream, None)
                        if item is None:
                            break
                        if item[0] == "group":
                            item = _unfinished(item, streamed)
                            if item is None:
                                continue
                        try:
                            fut = _submit(pool, scenario, item, files)
                        except BrokenProcessPool:
                            retry.appendleft(item)
                            raise
                        in_flight[fut] = item
                    if not in_flight:
                        break
                    finished, _ = cf.wait(list(in_flight), timeout=None if pool.dask else 0.5,
                                          return_when=cf.FIRST_COMPLETED)
                    drain()
                    for fut in finished:
                        result = fut.result()
                        take(in_flight.pop(fut), result)
                    maybe_commit()
                break
            except BrokenProcessPool:
                pool.check_broken()
                drain()
                lost = []
                for fut, item in in_flight.items():
                    if fut.done() and not fut.cancelled() and fut.exception() is None:
                        take(item, fut.result())
                    else:
                        lost.append(item)
                in_flight.clear()
                retry.extendleft(reversed(lost))
                store.commit()
                restarts += 1
                if restarts > MAX_POOL_RESTARTS:
                    left = plan.pending - counts["ran"]
                    raise PbdynError(f"worker processes died {restarts} times; {left} trials not run (re-run the "
                                     "same command to resume)") from None
                sys.stderr.write(f"pbdyn batch: a worker died; restarting the pool ({restarts}/"
                                 f"{MAX_POOL_RESTARTS}) and resuming\n")
                pool.restart()
        store.commit()
    except KeyboardInterrupt:
        interrupted = True
        drain()                                     # rows of trials that ended inside groups still in flight
        for fut, item in list(in_flight.items()):   # keep what has arrived
            if fut.done() and not fut.cancelled() and fut.exception() is None:
                take(item, fut.result())
        raise
    finally:
        try:
            store.commit()
        finally:
            pool.close(terminate=interrupted)
    return counts["ran"], counts["errors"], counts["maps"]


def _grouped(items: Iterator[tuple], size: int) -> Iterator[tuple]:
    """The stream of ("map", map, False) and ("trial", trial, replaces) items with runs of consecutive trials of one
    map packed into ("group", [trials], [replaces]) items of at most ``size`` (size 1: unchanged)."""
    if size <= 1:
        yield from items
        return
    trials: list = []
    reps: list = []
    for item in items:
        kind, obj, rep = item
        if trials and (kind != "trial" or obj[1].map_id != trials[0][1].map_id or len(trials) >= size):
            yield "group", trials, reps
            trials, reps = [], []
        if kind == "trial":
            trials.append(obj)
            reps.append(rep)
        else:
            yield item
    if trials:
        yield "group", trials, reps


def _unfinished(item: tuple, streamed: dict) -> tuple | None:
    """A lockstep group item without the trials whose rows have already been stored (a group re-queued after its
    worker died); registers the rest in ``streamed`` (key -> (replaces, taken)). None if nothing is left."""
    _, trials, reps = item
    keep = [(t, r) for t, r in zip(trials, reps) if not streamed.get(t[0], (r, False))[1]]
    if not keep:
        for t in trials:
            streamed.pop(t[0], None)
        return None
    for t, r in keep:
        streamed[t[0]] = (r, False)
    return "group", [t for t, _ in keep], [r for _, r in keep]


def _trial_spec_of(scenario: Scenario, trial, files: dict):
    """(key, TrialSpec, RolloutRef) of one enumerated trial."""
    key, m, entry, v, start, goal = trial
    if m.map_id not in files:     # not foreseen (the store changed under the batch): build it now
        files[m.map_id] = rollout_file(scenario, m, default_horizon(scenario))
    rkey, path = files[m.map_id]
    return key, trial_spec(scenario, m, entry, v, start, goal), RolloutRef(rkey, str(path))


def _submit(pool: _Pool, scenario: Scenario, item, files: dict):
    kind, obj, _ = item
    if kind == "group":
        specs = [_trial_spec_of(scenario, t, files) for t in obj]
        ref = specs[0][2]
        task = TrialGroupTask(tuple(k for k, _, _ in specs), tuple(s for _, s, _ in specs), ref)
        return pool.submit(run_trial_group_task, task, ref.key, Path(ref.path))
    if kind == "map":
        key, path = files[obj.map_id]
        return pool.submit(run_map_task, MapTask(scenario, obj, RolloutRef(key, str(path)), METRIC_SET, "auto"),
                           key, path)
    key, spec, ref = _trial_spec_of(scenario, obj, files)
    return pool.submit(run_trial_task, TrialTask(key, spec, ref), ref.key, Path(ref.path))
