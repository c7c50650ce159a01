"""pbdyn.experiments: batches of trials, their workers and results stores. Here: the one thread-limit setup."""

import os


def limit_threads() -> None:
    """One BLAS/OpenMP thread (docs/design.md "Determinism") unless the environment sets another count: for this
    process if numpy is not imported yet, and for the worker processes started after the call."""
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
