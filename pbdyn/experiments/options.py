"""What a batch is asked to do (BatchOptions): read by the runner (pbdyn.experiments.runner), the plan
(pbdyn.experiments.plan) and the dispatch loop (pbdyn.experiments.dispatch), below all three."""

from __future__ import annotations

from dataclasses import dataclass

LOCKSTEP_TRIALS = 72
"""Default most trials of one map flown together per task (one planner pair's start/goal pairs at one speed)."""


@dataclass(frozen=True)
class BatchOptions:
    """workers: local processes (default: CPU count); scheduler: a Dask scheduler address ("tcp://host:8786") or
    a dask.distributed Client; limit: fly only the first N trials of the enumeration; extend: accept a scenario
    that adds grid values, planners, MAV speeds or maps to the one in the store; metrics: compute each map's
    metrics (METRIC_SET); progress: a progress line on stderr, or a pbdyn.experiments.progress.Progress that
    several batches share (one line and one ETA over all of them; pending_trials_of counts each batch's trials);
    rerun_changed: re-fly stored rows whose planner fingerprint differs from the current code's, and the maps whose
    world changed (else such rows stop the batch); retry_errors: re-fly stored "error" rows; lockstep: most trials
    of one map per task; shard: (I, N) or "I/N", fly only part I of N (pbdyn.experiments.shards)."""

    workers: int | None = None
    scheduler: object = None
    limit: int | None = None
    extend: bool = False
    metrics: bool = True
    progress: bool | object = True
    rerun_changed: bool = False
    retry_errors: bool = False
    lockstep: int = LOCKSTEP_TRIALS
    shard: tuple[int, int] | None = None
