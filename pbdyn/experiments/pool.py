"""The workers of a batch (WorkerPool): a local process pool or a Dask client's executor.

Local workers are spawned, never forked from a process holding a PyBullet client, with BLAS/OpenMP threads = 1;
they send each lockstep group's rows through a queue as each trial ends. Dask workers get a map's rollout as bytes,
scattered once per map, and return a group's rows with its result (docs/experiments.md, "Workers" and "Dask").
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
import queue as queue_module
from collections.abc import Iterator
from pathlib import Path

from pbdyn.experiments import limit_threads
from pbdyn.experiments.cluster import connect
from pbdyn.experiments.mainguard import PoolGuard
from pbdyn.experiments.tasks import worker_init


class WorkerPool:
    """A process pool (spawn context, BLAS/OpenMP threads = 1 in workers) or a Dask client's executor. ``what``:
    the name of the call that owns a local pool (run_batch, generate_maps; named by a MainGuardError).

    Local workers ignore SIGINT and exit within PARENT_POLL_S of their coordinator's death (tasks.worker_init);
    close(terminate=True) ends them at once (the owner's SIGTERM/SIGINT path, pbdyn.experiments.signals)."""

    def __init__(self, workers: int, scheduler=None, what: str = "run_batch"):
        self.client = None
        self.own_client = False
        self.workers = workers
        self.what = what
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
        limit_threads()
        if self.guard is None:
            self.guard = PoolGuard(self.what)
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
        """True for a Dask client's executor, False for a local process pool."""
        return self.client is not None

    def check_broken(self) -> None:
        """After the pool broke: MainGuardError if a worker died re-importing a main script that calls run_batch at
        its top level (pbdyn.experiments.mainguard): restarting would only break it again."""
        if self.guard is not None:
            self.guard.check()

    def restart(self) -> None:
        """Replace a broken local pool: its executor is shut down (running tasks cancelled), its queue closed, and
        a new queue and new worker processes started."""
        self.executor.shutdown(wait=False, cancel_futures=True)
        self.queue.close()
        self._start()

    def exit_codes(self) -> list[int | None]:
        """The exit codes of this local pool's worker processes (None: still running), after it broke: the worker
        that died shows its own (e.g. -11 for SIGSEGV), the others -15 once the executor has ended them."""
        procs = list((getattr(self.executor, "_processes", None) or {}).values())
        for p in procs:
            p.join(2.0)
        return [p.exitcode for p in procs]

    def submit(self, fn, task, key: str = "", path: Path | None = None):
        """Submit fn(task) -- for Dask fn(task, data) with the rollout's bytes scattered once per map (``key``,
        ``path``)."""
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
